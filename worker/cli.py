"""`cmrt worker` / `python -m worker`: start a Celery evaluation worker."""

from __future__ import annotations

import argparse
import os
import sys


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="cmrt worker",
        description="Start a Celery worker evaluating CMRT candidates (needs CMRT_BROKER_URL).",
    )
    p.add_argument("--concurrency", "-c", type=int, default=int(os.environ.get(
        "CMRT_WORKER_CONCURRENCY", "0") or 0) or None,
        help="worker processes (default: the number of CPUs)")
    p.add_argument("--loglevel", "-l", default=os.environ.get("CMRT_LOG_LEVEL", "INFO"))
    p.add_argument("--hostname", "-n", default=None, help="node name (default cmrt@<host>)")
    p.add_argument("--ping", action="store_true",
                   help="health check: exit 0 if a worker on this host answers a ping")
    return p


def worker_main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from cmrt.settings import get_settings

    if not getattr(get_settings(), "broker_url", None):
        print("cmrt worker: no broker configured (set CMRT_BROKER_URL, e.g. redis://localhost:6379/0);"
              " without a broker `cmrt serve` evaluates in its own local process pool",
              file=sys.stderr)
        return 2
    from worker.celery_app import app
    from worker.config import get_worker_config

    if args.ping:
        import socket

        name = args.hostname or f"cmrt@{socket.gethostname()}"
        replies = app.control.ping(destination=[name], timeout=5.0)
        return 0 if replies else 1
    cmd = ["worker", "-Q", get_worker_config().queue, "-l", args.loglevel, "--without-gossip",
           "--without-mingle", "-P", "prefork"]
    if args.concurrency:
        cmd += ["-c", str(args.concurrency)]
    cmd += ["-n", args.hostname or "cmrt@%h"]
    app.worker_main(cmd)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(worker_main())
