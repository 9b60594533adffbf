"""Imported by the slot pools' fork servers (optim.procpool.SIMULATOR_PRELOAD): one tiny
simulation loads the simulator's compiled (numba-cached) code into the fork server, so every
slot process forked from it starts with it loaded (a killed slot's successor is ready in
about a tenth of a second instead of seconds)."""

from __future__ import annotations

import contextlib


def _warm() -> None:
    from sim.rollout import Rollout
    from sim.spec import parse_spec

    spec = parse_spec({"name": "slot_warm_up", "family": "warm",
                       "clip": {"preparation": 0.02, "duration": 0.02, "decay": 0.02},
                       "task": {"type": "quiet_stance"}}, "<slot warm-up>")
    sim = Rollout(spec)
    try:
        sim.run(None)
    finally:
        sim.close()


with contextlib.suppress(Exception):  # only a speed-up: a slot warms up on first use anyway
    _warm()
