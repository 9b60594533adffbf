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


def run_bench(seconds: float = 5.0) -> dict[str, float]:
    """Measure both cases in this process; returns CPU seconds per simulated second and ratio."""
    sim = Rollout(_spec(seconds))
    Rollout(_spec(0.05)).run()  # warm-up: numba compilation and caches
    raw = raw_ode_cpu_per_second(sim, seconds)
    t0 = time.process_time()
    ev = sim.run()
    full = (time.process_time() - t0) / ev.sim_seconds
    sim.close()
    return {
        "simulated_seconds": seconds,
        "raw_ode_cpu_per_sim_second": raw,
        "controller_cpu_per_sim_second": full,
        "controller_over_raw_ode": full / raw,
        "paper_cpp_cpu_per_sim_second": 0.5,
        "faster_than_real_time": 1.0 / full,
    }


def run_task_bench(spec: TaskSpec, seconds: float = 5.0) -> dict[str, float | str | int]:
    """Raw ODE stepping of `spec`'s world for `seconds` against its clip under the controller
    (no CMRT), in this process after a warm-up; CPU seconds per simulated second and ratio."""
    sim = Rollout(spec)
    sim.run()  # warm-up: numba compilation, caches, the world's first contacts
    raw = raw_ode_cpu_per_second(sim, seconds)
    t0 = time.process_time()
    ev = sim.run()
    full = (time.process_time() - t0) / ev.sim_seconds
    props = len(sim.physics.props)
    sim.close()
    return {
        "spec": spec.name,
        "props": props,
        "controller_simulated_seconds": ev.sim_seconds,
        "raw_ode_cpu_per_sim_second": raw,
        "controller_cpu_per_sim_second": full,
        "controller_over_raw_ode": full / raw,
    }
