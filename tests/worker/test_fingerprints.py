"""worker.fingerprints: the records in Redis (live workers only) and a fingerprint that a
caller gets without waiting for the reference clip."""

from __future__ import annotations

import os
import time
import uuid

import pytest

from sim.fingerprint import numeric_fingerprint
from worker.fingerprints import (
    KEY_PREFIX,
    TTL_SECONDS,
    fingerprint_if_ready,
    live_fingerprints,
    publish,
    record,
    redis_client,
)

REDIS = os.environ.get("CMRT_TEST_REDIS", "redis://127.0.0.1:6379")


def test_the_fingerprint_comes_from_the_background_and_equals_the_computed_one() -> None:
    t0 = time.monotonic()
    got = fingerprint_if_ready()
    while got is None and time.monotonic() - t0 < 120:
        time.sleep(0.05)
        got = fingerprint_if_ready()
    assert got == numeric_fingerprint().digest and len(got) == 16
    assert record("w@h") == {"hostname": "w@h", **numeric_fingerprint().to_dict()}


def test_a_non_redis_broker_has_no_registry() -> None:
    assert redis_client("memory://") is None and redis_client("") is None


@pytest.mark.redis
def test_records_expire_and_only_live_ones_are_read() -> None:
    import redis

    client = redis_client(REDIS + "/0")
    try:
        client.ping()
    except redis.ConnectionError as err:
        pytest.skip(f"Redis at {REDIS} unreachable ({err})")
    host = f"fp-{uuid.uuid4().hex[:8]}@test"
    publish(client, {"hostname": host, "fingerprint": "0123456789abcdef"})
    junk = KEY_PREFIX + f"junk-{uuid.uuid4().hex[:8]}"
    client.set(junk, b"not json", ex=TTL_SECONDS)
    try:
        assert live_fingerprints(client)[host] == "0123456789abcdef"
        assert 0 < client.ttl(KEY_PREFIX + host) <= TTL_SECONDS
        client.delete(KEY_PREFIX + host)  # what expiry does to a dead worker's record
        assert host not in live_fingerprints(client)
    finally:
        client.delete(KEY_PREFIX + host, junk)
