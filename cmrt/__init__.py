"""The product's public face: what a user imports and what every edge of the product shares.

The package carries the product's name; it holds no CMRT (a CMRT is an `optim.spline.CmrtSpline`,
stored as a `store.records.CmrtRecord`, served by `application.library`). Its modules:

- `cmrt.client`: the Python client of the HTTP API, what a user imports (`from cmrt.client import
  Client`); `cmrt submit / jobs / watch / library` run on it;
- `cmrt.settings`: the one configuration of every process (the `CMRT_*` variables);
- `cmrt.canonical`: the canonical text and hash of a document that is stored or crosses a
  process boundary (a task spec, a family request);
- `cmrt.specfile`: a spec file as every command line reads it, the blocks it takes from other
  files (`task: {file: ...}`, `character: {file: ...}`) inline;
- `cmrt.cmdline`: what every command line shares (the `cmrt` command and `python -m service` /
  `python -m worker`): the one-line error, argument types, a process's settings and logging.

Each imports nothing of the product beyond this package, so every layer, `sim/` to `cli/`, may
import it (docs/architecture.md). The `cmrt` command itself is `cli/` (`cli.main:main`).
"""
