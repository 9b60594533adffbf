"""A TCP forwarder: `python tcp_forward.py LISTEN_HOST LISTEN_PORT TARGET_HOST TARGET_PORT`.

The topology tests' worker host (a network namespace, see harness.NetnsHost) reaches the
machine's PostgreSQL through this: the server listens on 127.0.0.1 of the root namespace only,
which another namespace cannot reach, so the harness runs one forwarder on the host side of the
veth link. Each accepted connection gets its own connection to the target; bytes are copied both
ways, and when either side closes or fails, both are closed (a session terminated by the server
reaches the client as a closed connection, as it would without the forwarder). No timeouts of
its own: a silent client (a cut link) is left to the client's and the server's TCP, exactly as
a direct connection would be. Prints "listening" once bound; SIGTERM ends it.
"""

from __future__ import annotations

import asyncio
import contextlib
import signal
import sys

CHUNK_BYTES = 65536


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    try:
        while data := await reader.read(CHUNK_BYTES):
            writer.write(data)
            await writer.drain()
    except (ConnectionError, OSError):
        pass
    finally:
        with contextlib.suppress(Exception):
            writer.close()


async def _serve(listen_host: str, listen_port: int, target_host: str, target_port: int) -> None:
    async def handle(c_reader: asyncio.StreamReader, c_writer: asyncio.StreamWriter) -> None:
        peer = c_writer.get_extra_info("peername")
        try:
            t_reader, t_writer = await asyncio.open_connection(target_host, target_port)
        except OSError as err:
            print(f"tcp_forward: {peer}: target unreachable: {err}", flush=True)
            c_writer.close()
            return
        a = asyncio.create_task(_pipe(c_reader, t_writer))
        b = asyncio.create_task(_pipe(t_reader, c_writer))
        await asyncio.wait({a, b}, return_when=asyncio.FIRST_COMPLETED)
        for w in (c_writer, t_writer):  # one side ended: end the other
            with contextlib.suppress(Exception):
                w.close()
        for t in (a, b):
            t.cancel()

    server = await asyncio.start_server(handle, listen_host, listen_port, reuse_address=True)
    print(f"tcp_forward: listening on {listen_host}:{listen_port} -> "
          f"{target_host}:{target_port}", flush=True)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    async with server:
        await stop.wait()


def main(argv: list[str]) -> int:
    if len(argv) != 4:
        print(__doc__.splitlines()[0], file=sys.stderr)
        return 2
    listen_host, listen_port, target_host, target_port = argv
    asyncio.run(_serve(listen_host, int(listen_port), target_host, int(target_port)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
