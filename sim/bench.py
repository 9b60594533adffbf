"""Speed of the simulation core: CPU seconds per simulated second, full controller vs raw ODE.

Both cases run in the same process, one after the other, after a warm-up (numba compilation
is excluded): `raw_ode` steps the same humanoid world with its four heel/toe ground contacts
made, stepped and cleared each step, no controller (the world is reset to the standing pose
every RAW_RESET_SECONDS so it stays in a standing configuration); `controller` runs the quiet
stance clip through `Rollout.run` (state read-back, model terms, QP at 60 Hz, inverse
dynamics, CP measurement).

`run_task_bench(spec)` does the same for any task spec: raw ODE stepping of that spec's world
(the character and every prop, the props collided with the ground, each other and the hands
each step, no controller and no task events) against the whole clip under the controller with
its task (no CMRT). A clip that falls ends early: the rate is over the seconds it simulated.

Both also report `replay_ode_cpu_per_sim_second`: the clip's own world stepped again with the
controller's torques and contact points replayed open loop (`replay_ode_cpu_per_second`). The
raw case above steps the world as it is built (a pull's chain not yet joined to the hands and
the box, a catch's ball resting where it was defined), with no torques; the replay steps what
the clip stepped (the same joints, contacts, throws and catches, the same trajectory bit for
bit), so full minus replay is exactly what the controller and the measurements add.
"""

from __future__ import annotations

import time

import numpy as np

from sim.physics import DT
from sim.rollout import Rollout
from sim.spec import TaskSpec, parse_spec

RAW_RESET_SECONDS = 0.5


def _spec(seconds: float):
    return parse_spec({"name": "bench_quiet_stance", "task": {"type": "quiet_stance"},
                       "clip": {"preparation": 0.0, "duration": seconds, "decay": 0.0}})


def raw_ode_cpu_per_second(sim: Rollout, seconds: float) -> float:
    """CPU seconds per simulated second of stepping `sim`'s world alone (see the module)."""
    w, ch = sim.physics, sim.character
    has_props = bool(w.props)
    pts = np.concatenate([[h, t] for h, t in zip(ch.heel0, ch.toe0, strict=True)])
    pts[:, 1] = 0.0
    feet = np.repeat(ch.feet, 2).tolist()
    steps = int(round(seconds / DT))
    every = int(round(RAW_RESET_SECONDS / DT))
    cpu = 0.0
    for k in range(steps):
        if k % every == 0:
            w.reset(sim.q0)
        t0 = time.process_time()
        w.make_contacts(pts, feet)
        if has_props:
            w.collide_props()
        w.step()
        w.contact_forces()
        w.clear_contacts()
        cpu += time.process_time() - t0
    return cpu / seconds


def replay_ode_cpu_per_second(sim: Rollout) -> tuple[float, float, bool]:
    """(CPU s per simulated s, simulated s, reproduced): run `sim`'s clip (no CMRT) recording
    the torques and foot contact points of every step, then step the same world again from
    the same start replaying them, with the task's events (throws, catches, pushes) and prop
    collisions, and no controller, state read-back or measurement. `reproduced` is True when
    the replay ended with every body and prop where the clip left it, bit for bit."""
    phys = sim.physics
    apply_torques, make_contacts = phys.apply_torques, phys.make_contacts
    taus: list[np.ndarray] = []
    points: list[np.ndarray] = []

    def record_torques(tau: np.ndarray) -> None:
        taus.append(np.array(tau, dtype=float))
        apply_torques(tau)

    def record_contacts(pts: np.ndarray, feet: list[int]) -> None:
        points.append(pts.copy())
        make_contacts(pts, feet)

    def record_clamped(tau: list[float]) -> None:
        taus.append(np.array(tau, dtype=float))  # clamped already: apply_torques keeps it
        add_clamped(tau)

    add_clamped = phys.add_clamped_torques
    phys.apply_torques, phys.make_contacts = record_torques, record_contacts
    phys.add_clamped_torques = record_clamped
    try:
        sim.run()
    finally:
        # the class's methods again
        del phys.apply_torques, phys.make_contacts, phys.add_clamped_torques
    end = phys.poses()
    task = sim.task
    events = task.events
    feet = np.repeat(sim.character.feet, 2).tolist()
    step, collide, forces, clear = (phys.step, phys.collide_props, phys.contact_forces,
                                    phys.clear_contacts)
    has_props = bool(phys.props)
    phys.reset(sim.q0)
    task.reset(phys)
    t0 = time.process_time()
    for k, (tau, pts) in enumerate(zip(taus, points, strict=True)):
        t = k * DT
        apply_torques(tau)
        if events:
            task.before_step(phys, t)
        make_contacts(pts, feet)
        if has_props:
            collide()
        step()
        forces()
        if events:
            task.after_step(phys, t + DT)
        clear()
    cpu = time.process_time() - t0
    seconds = len(taus) * DT
    return cpu / seconds, seconds, phys.poses() == end


def _repeated(sim: Rollout, seconds: float, repeat: int) -> dict[str, float | bool | list]:
    """`repeat` rounds of (raw ODE for `seconds`, the clip under the controller, its replay) on
    `sim`, each round in that order so that a change of the machine's load reaches all three.
    The rates are the totals' (CPU s over simulated s); the ratios' per-round values are
    listed too (`*_runs`), for their range."""
    raw_cpu = full_cpu = full_sim = replay_cpu = replay_sim = 0.0
    same = True
    over_raw: list[float] = []
    over_replay: list[float] = []
    for _ in range(repeat):
        raw = raw_ode_cpu_per_second(sim, seconds)
        t0 = time.process_time()
        ev = sim.run()
        cpu = time.process_time() - t0
        replay, replayed, same_run = replay_ode_cpu_per_second(sim)
        raw_cpu += raw * seconds
        full_cpu += cpu
        full_sim += ev.sim_seconds
        replay_cpu += replay * replayed
        replay_sim += replayed
        same = same and same_run
        over_raw.append(cpu / ev.sim_seconds / raw)
        over_replay.append(cpu / ev.sim_seconds / replay)
    raw = raw_cpu / (seconds * repeat)
    full = full_cpu / full_sim
    replay = replay_cpu / replay_sim
    return {
        "controller_simulated_seconds": full_sim / repeat,
        "raw_ode_cpu_per_sim_second": raw,
        "controller_cpu_per_sim_second": full,
        "controller_over_raw_ode": full / raw,
        "replay_ode_cpu_per_sim_second": replay,
        "controller_over_replay_ode": full / replay,
        "replay_reproduced_clip": same,
        "repeat": repeat,
        "controller_over_raw_ode_runs": over_raw,
        "controller_over_replay_ode_runs": over_replay,
    }


def run_bench(seconds: float = 5.0, repeat: int = 1) -> dict[str, float | bool | list]:
    """Measure both cases in this process; returns CPU seconds per simulated second and ratio.
    `repeat` > 1: that many rounds, the rates over all of them (see `_repeated`)."""
    sim = Rollout(_spec(seconds))
    Rollout(_spec(0.05)).run()  # warm-up: numba compilation and caches
    r = _repeated(sim, seconds, repeat)
    sim.close()
    full = r.pop("controller_cpu_per_sim_second")
    r.pop("controller_simulated_seconds")
    return {
        "simulated_seconds": seconds,
        "raw_ode_cpu_per_sim_second": r.pop("raw_ode_cpu_per_sim_second"),
        "controller_cpu_per_sim_second": full,
        **r,
        "paper_cpp_cpu_per_sim_second": 0.5,
        "faster_than_real_time": 1.0 / full,
    }


def run_task_bench(spec: TaskSpec, seconds: float = 5.0,
                   repeat: int = 1) -> dict[str, float | str | int | bool | list]:
    """Raw ODE stepping of `spec`'s world for `seconds` against its clip under the controller
    (no CMRT), in this process after a warm-up; CPU seconds per simulated second and ratio.
    A clip that falls early is short (1-3 s) and its single figure noisy: `repeat` > 1 runs
    that many rounds and reports the rates over all of them (see `_repeated`)."""
    sim = Rollout(spec)
    sim.run()  # warm-up: numba compilation, caches, the world's first contacts
    r = _repeated(sim, seconds, repeat)
    props = len(sim.physics.props)
    sim.close()
    return {"spec": spec.name, "props": props, **r}
