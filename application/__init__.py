"""The service's use cases, shared by the HTTP API (`service/`) and the job and family drivers
and evaluation workers (`worker/`):

- `application.admission`: a job's or a family's budget against the server's ceiling;
- `application.jobs`: submitting a job (its basis, budget and library start) and a stored job's
  typed spec, found by its hash in the process's one spec cache;
- `application.library`: the library of learned CMRTs (interpolation, where a new job starts);
- `application.bases`: PCA bases (built from the library, stored, read back for a job);
- `application.families`: submitting a family and a stored family's typed request;
- `application.characters`: characters kept by name, and their use in specs;
- `application.simulations`: what-if simulations, replays and a job's motion files, run in the
  API's simulation pool.

Imports `store`, `optim`, `sim` and `cmrt`; never fastapi, celery or redis, and nothing of
`service/` or `worker/` (both import it at module top).
"""
