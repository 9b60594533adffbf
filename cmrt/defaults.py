"""Defaults every edge shares, so that the same request gives the same result whichever door
it comes through (`cmrt optimize`, `cmrt family run`, `POST /jobs`, `POST /families`, a
refinement, the Python client)."""

from __future__ import annotations

#: CMA-ES seed of a run that names none. One value for the command line and the service: the
#: same spec optimised by `cmrt optimize` and by a job submitted without a seed gives the same
#: CMRT, and the job's record holds the seed it ran with.
DEFAULT_SEED = 1

__all__ = ["DEFAULT_SEED"]
