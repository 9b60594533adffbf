"""Workers' numeric fingerprints (`sim.fingerprint`): computed at a worker's start, logged, and
reported three ways (docs/service.md, "Numeric fingerprints"):

- in Redis, `cmrt:fingerprint:<worker hostname>` -> its record as JSON, written at start and
  refreshed every `REFRESH_SECONDS` with a time to live of `TTL_SECONDS`, so the keys present
  are the live workers' (`/health` reads them, `live_fingerprints`);
- in Celery's `inspect stats` (what Flower's worker page shows), under `cmrt_fingerprint`;
- by the remote-control command `celery -A worker.celery_app inspect fingerprint`.

Each evaluation a worker stores carries its process's fingerprint (worker.candidates).
"""

from __future__ import annotations

import contextlib
import functools
import json
import logging
import threading
from typing import Any

from celery import bootsteps
from celery.worker.control import inspect_command

log = logging.getLogger("cmrt.worker.fingerprint")

#: Redis key prefix of a worker's record (the worker's hostname follows).
KEY_PREFIX = "cmrt:fingerprint:"
#: A worker's record expires this long (s) after its last refresh: a dead worker's drops out.
TTL_SECONDS = 60
#: How often (s) a live worker refreshes its record (a third of the TTL: two can be missed).
REFRESH_SECONDS = 20
#: The most worker records `/health` reads (a fleet larger than this is summarised by them).
MAX_LISTED = 256


def process_fingerprint() -> str:
    """This process's fingerprint (computed once per process: ~0.1 s of CPU the first time)."""
    from sim.fingerprint import numeric_fingerprint

    return numeric_fingerprint().digest


_background = threading.Lock()
_started = False


def fingerprint_if_ready() -> str | None:
    """This process's fingerprint when it has been computed, else None after starting its
    computation in a background thread (once): a caller that must answer at once (`/health`)
    never waits for the reference clip (in a fresh container its first run compiles the
    simulator, tens of seconds)."""
    from sim.fingerprint import numeric_fingerprint

    if numeric_fingerprint.cache_info().currsize:
        return numeric_fingerprint().digest
    global _started
    with _background:
        if not _started:
            _started = True
            threading.Thread(target=numeric_fingerprint, name="cmrt-fingerprint",
                             daemon=True).start()
    return None


def record(hostname: str) -> dict[str, Any]:
    """What a worker reports: its hostname, fingerprint, reference clip hash and versions."""
    from sim.fingerprint import numeric_fingerprint

    return {"hostname": hostname, **numeric_fingerprint().to_dict()}


@functools.cache
def redis_client(url: str) -> Any:
    """A Redis client of `url` (one per process and URL), or None when it is not Redis."""
    if not url.startswith(("redis://", "rediss://", "unix://")):
        return None
    import redis

    return redis.Redis.from_url(url, socket_timeout=2.0, socket_connect_timeout=2.0)


def publish(client: Any, rec: dict[str, Any]) -> None:
    """Write (or refresh) a worker's record with its time to live."""
    client.set(KEY_PREFIX + rec["hostname"], json.dumps(rec), ex=TTL_SECONDS)


def live_fingerprints(client: Any) -> dict[str, str]:
    """Worker hostname -> fingerprint of the live workers' records (at most `MAX_LISTED`)."""
    keys = []
    for key in client.scan_iter(match=KEY_PREFIX + "*", count=100):
        keys.append(key)
        if len(keys) >= MAX_LISTED:
            break
    out: dict[str, str] = {}
    for raw in client.mget(keys) if keys else []:
        try:
            rec = json.loads(raw)
            out[str(rec["hostname"])] = str(rec["fingerprint"])
        except (TypeError, ValueError, KeyError):
            continue  # expired between the scan and the read, or not ours
    return out


class FingerprintStep(bootsteps.StartStopStep):
    """The worker's fingerprint: logged and published at start, refreshed on the worker's
    timer, withdrawn at a clean stop, and in `inspect stats` (`info`)."""

    requires = ("celery.worker.components:Timer",)

    def __init__(self, parent: Any, **kwargs: Any) -> None:
        super().__init__(parent, **kwargs)
        self.rec: dict[str, Any] | None = None
        self.client: Any = None
        self.tref: Any = None

    def start(self, parent: Any) -> None:
        self.rec = record(parent.hostname)
        log.info("numeric fingerprint %s (%s)", self.rec["fingerprint"],
                 ", ".join(f"{k} {v}" for k, v in self.rec["versions"].items()))
        self.client = redis_client(str(parent.app.conf.broker_url or ""))
        if self.client is not None:
            self._refresh()
            self.tref = parent.timer.call_repeatedly(REFRESH_SECONDS, self._refresh)

    def _refresh(self) -> None:
        try:
            publish(self.client, self.rec)
        except Exception as err:  # noqa: BLE001 - Redis away: the next refresh tries again
            log.warning("could not publish the numeric fingerprint: %s", err)

    def stop(self, parent: Any) -> None:
        if self.tref is not None:
            self.tref.cancel()
        if self.client is not None and self.rec is not None:
            with contextlib.suppress(Exception):  # it expires by itself anyway
                self.client.delete(KEY_PREFIX + self.rec["hostname"])

    def info(self, parent: Any) -> dict[str, Any]:
        return {"cmrt_fingerprint": self.rec}


@inspect_command(name="fingerprint")
def fingerprint_command(state: Any) -> dict[str, Any]:
    """`celery inspect fingerprint`: the worker's numeric fingerprint record."""
    return record(state.consumer.hostname)
