"""Result notices from the Celery workers to the job drivers, over the broker's Redis.

The store stays the only record of a result; a notice only says "look now". After a worker has
stored (or given up on) a candidate it appends `"<generation>:<index>"` to the job's list
`cmrt:done:<job id>` (one pipelined round trip: RPUSH + EXPIRE). The driver blocks on that list
(BLMPOP; BLPOP on Redis < 7) instead of polling the store, so it wakes when a result lands and
costs no CPU while the candidates run. A notice that never arrives (Redis restarted, the
worker's link cut after it stored the result, a broker that is not Redis) costs only latency:
the driver still reads the store at least every `FALLBACK_POLL_S` s, which is also how often
it reads the cancel flag.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Iterable
from typing import Any

log = logging.getLogger(__name__)

#: Prefix of the per-job notice lists in Redis.
KEY_PREFIX = "cmrt:done:"
#: A job's notice list expires this long after its last notice, s (a job whose driver died
#: leaves nothing behind for long).
KEY_TTL_S = 3600
#: Longest a driver blocks for notices before it reads the store anyway, s: bounds the latency of
#: a lost notice and of a cancel request (the driver reads the cancel flag every 0.5 s).
FALLBACK_POLL_S = 0.5
#: After a Redis error, how long notices are not tried again in this process, s.
RETRY_AFTER_S = 5.0


def notice_key(job_id: str) -> str:
    """The Redis list of a job's result notices."""
    return f"{KEY_PREFIX}{job_id}"


def _redis_client(url: str | None, socket_timeout: float | None) -> Any | None:
    if not url or not url.startswith(("redis://", "rediss://", "unix://")):
        return None
    import redis

    return redis.Redis.from_url(url, socket_timeout=socket_timeout,
                                socket_connect_timeout=2.0, health_check_interval=0)


class Notifier:
    """Worker side: `notify(job, generation, index)` after a candidate is resolved in the store.
    Never raises: a failed notice is logged once per `RETRY_AFTER_S` and skipped."""

    def __init__(self, url: str | None) -> None:
        self.url = url
        self._client: Any | None = None
        self._down_until = 0.0
        self._lock = threading.Lock()

    def notify(self, job_id: str, generation: int, index: int) -> bool:
        """Append the notice; True if Redis took it."""
        if time.monotonic() < self._down_until:
            return False
        try:
            with self._lock:
                if self._client is None:
                    self._client = _redis_client(self.url, socket_timeout=2.0)
                client = self._client
            if client is None:
                return False
            key = notice_key(job_id)
            pipe = client.pipeline(transaction=False)
            pipe.rpush(key, f"{int(generation)}:{int(index)}")
            pipe.expire(key, KEY_TTL_S)
            pipe.execute()
            return True
        except Exception as err:  # noqa: BLE001 - a notice is a hint: the store has the result
            self._down_until = time.monotonic() + RETRY_AFTER_S
            log.warning("result notice for job %s not sent (%s: %s); its driver will find the "
                        "result by reading the store", job_id, type(err).__name__, err)
            return False


class NoticeWaiter:
    """Driver side: blocks on a job's notice list. Thread safe (one connection per blocked
    call from redis-py's pool), so one waiter serves every driver of a process."""

    def __init__(self, url: str | None) -> None:
        # the socket timeout must outlast the longest BLPOP
        self._client = _redis_client(url, socket_timeout=FALLBACK_POLL_S + 5.0)
        self._down_until = 0.0
        self._blmpop = True  # until the server says it does not know BLMPOP

    @property
    def available(self) -> bool:
        """Whether notices can be waited for now (Redis broker, not in a back-off)."""
        return self._client is not None and time.monotonic() >= self._down_until

    def wait(self, job_id: str, timeout: float) -> list[tuple[int, int]] | None:
        """The (generation, index) notices of the job that arrived, waiting up to `timeout` s
        for the first; [] on a timeout; None if notices are unavailable (the caller sleeps
        and polls instead)."""
        if not self.available:
            return None
        key = notice_key(job_id)
        try:
            raw = self._pop(key, max(timeout, 0.001))
            if not raw:
                return []
        except Exception as err:  # noqa: BLE001 - fall back to polling the store
            self._down_until = time.monotonic() + RETRY_AFTER_S
            log.warning("job %s: result notices unavailable (%s: %s); polling the store",
                        job_id, type(err).__name__, err)
            return None
        return list(_parse(raw))

    def _pop(self, key: str, timeout: float) -> list[Any]:
        """Every notice queued under `key`, waiting up to `timeout` s for the first: one round
        trip (BLMPOP, Redis >= 7) where the server has it, else BLPOP then LPOP."""
        if self._blmpop:
            try:
                got = self._client.blmpop(timeout, 1, key, direction="LEFT", count=1000)
                return [] if got is None else list(got[1])
            except redis_response_error() as err:
                if "unknown command" not in str(err).lower():
                    raise
                self._blmpop = False  # an older server: two round trips from now on
        # BLPOP takes whole seconds on old servers; Redis >= 6 takes a float
        first = self._client.blpop([key], timeout=timeout)
        if first is None:
            return []
        raw = [first[1]]
        more = self._client.lpop(key, 1000)
        if more:
            raw.extend(more)
        return raw

    def discard(self, job_id: str) -> None:
        """Drop a job's pending notices (its generation is over)."""
        if self._client is None:
            return
        with contextlib.suppress(Exception):  # the list expires by itself
            self._client.delete(notice_key(job_id))


def redis_response_error() -> type[Exception]:
    import redis.exceptions

    return redis.exceptions.ResponseError


def _parse(raw: Iterable[bytes | str]) -> Iterable[tuple[int, int]]:
    for item in raw:
        text = item.decode() if isinstance(item, bytes) else str(item)
        g, _, i = text.partition(":")
        try:
            yield int(g), int(i)
        except ValueError:
            continue
