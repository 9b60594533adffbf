"""What every command line of the project shares: the `cmrt` command (`cli/`) and the entry
points `python -m service` / `python -m worker`, which parse their own options with the
pieces here so that they need not import `cli/` (imports point down only).

Domain errors become one clear line on stderr and exit status 2 (`die`).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import signal
import sys
import threading
import warnings
from collections.abc import Callable, Iterator
from typing import Any

EXIT_BAD_INPUT = 2


def die(msg: str, code: int = EXIT_BAD_INPUT) -> int:
    """Print `cmrt: error: MSG` on stderr and return the exit status `code` (bad input)."""
    print(f"cmrt: error: {msg}", file=sys.stderr)
    return code


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {n}")
    return n


def port(text: str) -> int:
    """An argparse type: a TCP port, 1..65535."""
    n = positive_int(text)
    if n > 65535:
        raise argparse.ArgumentTypeError(f"must be a port in 1..65535, got {n}")
    return n


def process_settings(args: argparse.Namespace) -> tuple[Any, str]:
    """The settings of a long-running process (`serve`, `driver`) with its --workers, and its
    log level, logging set up on stderr."""
    from cmrt.settings import get_settings

    settings = get_settings()
    if args.workers is not None:
        settings = settings.model_copy(update={"workers": args.workers})
    level = (args.log_level or settings.log_level).upper()
    logging.basicConfig(level=level, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return settings, level


def quiet_plotting_warning() -> None:
    """pycma warns on import when matplotlib is absent; plotting is not part of this tool."""
    warnings.filterwarnings("ignore", message="Could not import matplotlib")


@contextlib.contextmanager
def terminate_like_interrupt() -> Iterator[None]:
    """While a command runs, SIGTERM (`kill`, `docker stop`) unwinds like Ctrl-C, so `finally`
    blocks close the process pool and the store instead of leaving them to the OS. Servers
    that install their own handler (uvicorn, Celery) replace this one while they run."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set from the main thread
        return

    def handler(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def entry_point(prog: str, description: str,
                add_arguments: Callable[[argparse.ArgumentParser], None],
                run: Callable[[argparse.Namespace], int], argv: list[str] | None = None) -> int:
    """`python -m PACKAGE [options]`: parse the options a command declares and run it as the
    `cmrt` command does (SIGTERM as Ctrl-C, exit 130 when interrupted)."""
    p = argparse.ArgumentParser(prog=prog, description=description)
    add_arguments(p)
    args = p.parse_args(argv)
    quiet_plotting_warning()
    try:
        with terminate_like_interrupt():
            return run(args)
    except KeyboardInterrupt:
        print("\ncmrt: interrupted", file=sys.stderr)
        return 130
