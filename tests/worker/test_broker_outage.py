"""The driver's sends against a broker that is down (a private `redis-server`, real Celery
messages): a broker that comes back within CMRT_BROKER_DEADLINE costs only the wait, the
messages go out once it answers; one that stays down fails the job with the reason (what the
topology drills rely on: tests/integration/test_topology.py, the Redis restart and the cut
link)."""

from __future__ import annotations

import shutil
import socket
import subprocess
import threading
import time
import uuid

import pytest

from cmrt.settings import Settings
from worker.candidates import JobFailedError
from worker.celery_app import make_celery
from worker.executors import CeleryExecutor

pytestmark = pytest.mark.redis


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _executor(tmp_path, port: int, deadline: float) -> tuple[CeleryExecutor, Settings]:
    broker = f"redis://127.0.0.1:{port}/0"
    settings = Settings(data_dir=tmp_path, database_url=f"sqlite:///{tmp_path}/b.db",
                        broker_url=broker, broker_deadline=deadline,
                        queue=f"q{uuid.uuid4().hex[:8]}")
    return CeleryExecutor(settings, make_celery(broker, broker, settings)), settings


@pytest.fixture
def redis_server():
    if shutil.which("redis-server") is None:
        pytest.skip("no redis-server on this machine")
    procs: list[subprocess.Popen] = []

    def start(port: int) -> None:
        procs.append(subprocess.Popen(
            ["redis-server", "--port", str(port), "--bind", "127.0.0.1", "--save", "",
             "--appendonly", "no"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))

    yield start
    for p in procs:
        p.terminate()
        p.wait(10)


def test_a_send_waits_for_a_broker_that_comes_back(tmp_path, redis_server):
    import redis

    port = _free_port()
    ex, settings = _executor(tmp_path, port, deadline=60.0)
    checks: list[float] = []  # the checkpoint (cancel, lease) runs between failed tries
    down_for = 2.0
    starter = threading.Timer(down_for, redis_server, args=(port,))
    starter.start()
    t0 = time.monotonic()
    try:
        ex._send("job-outage", 0, [[0, 1], [2]], lambda: checks.append(time.monotonic()))
    finally:
        starter.cancel()
    waited = time.monotonic() - t0
    assert waited >= down_for, waited  # nothing went out while nothing answered
    assert ex.sent == 3 and ex.tasks == 2  # every message once, none dropped
    queued = redis.Redis(port=port, socket_timeout=5).llen(settings.queue)
    assert queued == 2
    print(f"\n[broker outage] sends waited {waited:.1f} s for a broker down {down_for:g} s; "
          f"{len(checks)} checkpoints; {queued} messages queued")


def test_a_broker_down_past_the_deadline_fails_the_job_with_the_reason(tmp_path):
    ex, _ = _executor(tmp_path, _free_port(), deadline=1.0)
    t0 = time.monotonic()
    with pytest.raises(JobFailedError) as err:
        ex._send("job-down", 0, [[0]], lambda: None)
    took = time.monotonic() - t0
    assert took >= 1.0
    assert str(err.value).startswith("the broker has been unreachable for ")
    assert "CMRT_BROKER_DEADLINE = 1 s" in str(err.value)
    assert ex.sent == 0
    # each try blocks in kombu's own connection retries (about 6 s against a refused port)
    print(f"\n[broker down] the send gave up after {took:.1f} s (deadline 1 s)")
