"""The `serve` command (`cmrt serve`, `python -m service`): the HTTP API with its job drivers
under uvicorn; the embedded default (SQLite file, local process pool) without a broker."""

from __future__ import annotations

import argparse
import logging

from cmrt.cmdline import die, entry_point, port, positive_int, process_settings

HELP = "run the HTTP API (embedded default: SQLite + local pool)"
DESCRIPTION = ("Serve the CMRT HTTP API and its job drivers. Without CMRT_BROKER_URL it runs the "
               "embedded default (SQLite file, evaluations in a local process pool), with no "
               "other server.")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The command's options, on `p` (the `cmrt serve` subparser or the entry point's parser)."""
    p.add_argument("--host", help="bind address (default CMRT_API_HOST, 127.0.0.1)")
    p.add_argument("--port", type=port, help="port (default CMRT_API_PORT, 8000)")
    p.add_argument("--workers", type=positive_int,
                   help="local pool processes in embedded mode (default CMRT_WORKERS)")
    p.add_argument("--log-level", help="uvicorn log level (default CMRT_LOG_LEVEL, info)")


def run(args: argparse.Namespace) -> int:
    """Serve until uvicorn stops; 2 with one clear line if the settings or database are
    unusable."""
    import gc

    import uvicorn

    from service.app import create_app
    from service.security import host_warning

    settings, level = process_settings(args)
    # the bind address is one of the host names the API answers to (service.security)
    settings = settings.model_copy(update={"api_host": args.host or settings.api_host,
                                           "api_port": args.port or settings.api_port})
    try:
        app = create_app(settings)
    except Exception as err:  # noqa: BLE001 - settings or database unusable: one clear line
        return die(f"serve: {err}")
    warning = host_warning(settings)
    if warning:
        logging.getLogger("cmrt.service").warning("serve: %s", warning)
    # What is imported and built by now lives as long as the process: out of the collector's
    # sight, a full collection walks only what requests made since (about 200,000 objects
    # walked otherwise: a 60-190 ms pause of every request in flight; bench/library_scale.py).
    gc.collect()
    gc.freeze()
    uvicorn.run(app, host=settings.api_host, port=settings.api_port,
                log_level=level.lower(), timeout_graceful_shutdown=5)
    return 0


def main(argv: list[str] | None = None) -> int:
    """`python -m service [options]`: the same options and behaviour as `cmrt serve`."""
    return entry_point("python -m service", DESCRIPTION, add_arguments, run, argv)
