"""`cmrt serve` / `python -m service`: the HTTP API (with its job drivers) under uvicorn."""

from __future__ import annotations

import argparse
import os
import sys


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="cmrt serve",
        description="Serve the CMRT HTTP API. Without CMRT_BROKER_URL it runs the embedded default "
                    "(SQLite file, evaluations in a local process pool), with no other server.",
    )
    p.add_argument("--host", default=os.environ.get("CMRT_API_HOST", "127.0.0.1"))
    p.add_argument("--port", type=int, default=int(os.environ.get("CMRT_API_PORT", "8000")))
    p.add_argument("--workers", type=int, default=None,
                   help="local pool processes in embedded mode (default: CPUs)")
    p.add_argument("--log-level", default=os.environ.get("CMRT_LOG_LEVEL", "info").lower())
    return p


def serve_main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    if args.workers is not None:
        os.environ["CMRT_WORKERS"] = str(args.workers)
    import uvicorn

    from service.app import create_app

    try:
        app = create_app()
    except Exception as err:  # settings or database unusable: one clear line, exit 2
        print(f"cmrt serve: {err}", file=sys.stderr)
        return 2
    uvicorn.run(app, host=args.host, port=args.port, log_level=args.log_level,
                timeout_graceful_shutdown=5)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(serve_main())
