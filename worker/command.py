"""The `worker` command (`cmrt worker`, `python -m worker`): a Celery worker evaluating
candidates from the queue CMRT_QUEUE (needs CMRT_BROKER_URL)."""

from __future__ import annotations

import argparse

from cmrt.cmdline import die, entry_point, positive_int

HELP = "run a Celery evaluation worker (needs CMRT_BROKER_URL)"
DESCRIPTION = ("Start a Celery worker evaluating CMRT candidates from the queue CMRT_QUEUE "
               "(needs CMRT_BROKER_URL).")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The command's options, on `p` (the `cmrt worker` subparser or the entry point's
    parser)."""
    p.add_argument("--concurrency", "-c", type=positive_int,
                   help="worker processes (default CMRT_WORKER_CONCURRENCY, else the CPUs)")
    p.add_argument("--loglevel", "-l", help="log level (default CMRT_LOG_LEVEL, INFO)")
    p.add_argument("--hostname", "-n", help="node name (default cmrt@<host>)")
    p.add_argument("--ping", action="store_true",
                   help="health check: exit 0 if a worker on this host answers a ping")


def run(args: argparse.Namespace) -> int:
    """Run the worker until Celery stops it (or, with --ping, 0 if a worker answers); 2 with
    one clear line without a broker."""
    from cmrt.settings import get_settings

    settings = get_settings()
    if not settings.broker_url:
        return die("worker: no broker configured (set CMRT_BROKER_URL, e.g. "
                   "redis://localhost:6379/0); without a broker `cmrt serve` evaluates in its "
                   "own local process pool")
    from worker.celery_app import app

    if args.ping:
        import socket

        name = args.hostname or f"cmrt@{socket.gethostname()}"
        replies = app.control.ping(destination=[name], timeout=5.0)
        return 0 if replies else 1
    cmd = ["worker", "-Q", settings.queue, "-l", (args.loglevel or settings.log_level).upper(),
           "--without-gossip", "--without-mingle", "-P", "prefork"]
    concurrency = args.concurrency or settings.worker_concurrency
    if concurrency:
        cmd += ["-c", str(concurrency)]
    cmd += ["-n", args.hostname or "cmrt@%h"]
    import gc

    import worker.tasks  # noqa: F401 - the simulator and store, imported before the pool forks
    from worker.fingerprints import process_fingerprint

    process_fingerprint()  # the reference clip once, before the fork: the pool inherits it

    # Keep what is imported shared between the pool processes: without this, the first garbage
    # collection in each forked process writes to every object's header and so copies the
    # parent's pages (64 MB of private memory per pool process; 18 MB with it; bench/capacity.py).
    gc.freeze()
    app.worker_main(cmd)
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m worker [options]`: the same options and behaviour as `cmrt worker`."""
    return entry_point("python -m worker", DESCRIPTION, add_arguments, run, argv)
