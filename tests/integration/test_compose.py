"""What only the compose topology shows (CMRT_IT_MODE=compose, `make test-compose`): volumes
outliving `docker compose down`, `--scale worker=3` spreading one job over three containers,
`docker compose stop worker` (SIGTERM) mid-generation, and the API published on the loopback
only. Each test leaves the topology as the session fixture made it (two healthy workers, the
api up).
"""

from __future__ import annotations

import socket
import subprocess
import time

import pytest
from conftest import (
    WORKER_FAULTS,
    bend,
    bookkeeping,
    same_as_uninterrupted,
    submit,
    wait_job,
)

pytestmark = [pytest.mark.redis, pytest.mark.postgres]


@pytest.fixture
def compose(topology):
    if topology.mode != "compose":
        pytest.skip("compose mode only (CMRT_IT_MODE=compose, `make test-compose`)")
    return topology


def _two_workers(topo) -> None:
    """The session's topology again: two running, ready workers."""
    topo.scale("worker", 2)
    topo.wait_workers_ready(2)


def _report(what: str, book: dict) -> None:
    print(f"\n[{what}] expected={book['expected']} stored={book['done']} lost={book['lost']} "
          f"repeated={book['repeated']} failed={book['failed']}")


def test_down_then_up_keeps_the_library(api, compose):
    """`docker compose down` (containers and network removed, volumes kept) then up again: the
    library entry and the job made before are still there, and a new job runs."""
    job_id = submit(api, bend("it_volume", 0.3, threshold=5.0))
    job = wait_job(api, job_id)
    assert job["status"] == "converged" and job["cmrt_id"], job
    entry = api.get(f"/cmrts/{job['cmrt_id']}").json()
    before = {c.id for cs in compose.procs.values() for c in cs}

    compose.compose("down", "--timeout", "20")
    assert compose.compose("ps", "-a", "-q").split() == []
    volumes = compose.docker("volume", "ls", "-q", "--filter",
                             f"label=com.docker.compose.project={compose.project}").split()
    assert sorted(volumes) == [f"{compose.project}_pgdata", f"{compose.project}_redisdata"]

    compose.start_redis()
    compose.create_database()
    compose.start("worker", WORKER_FAULTS)
    compose.start("worker", WORKER_FAULTS)
    compose.start("api")
    compose.wait_workers_ready(2)
    after = {c.id for name in ("redis", "postgres", "api", "worker")
             for c in compose._containers(name) if c.alive}
    assert not after & before  # every container is a new one
    assert api.get(f"/cmrts/{job['cmrt_id']}").json() == entry
    assert api.get(f"/jobs/{job_id}").json()["status"] == "converged"
    again = wait_job(api, submit(api, bend("it_volume_after", 0.5, threshold=5.0)))
    assert again["status"] == "converged", again


def test_scale_worker_3_spreads_one_job_over_three_containers(api, compose):
    """`--scale worker=3`: one job's evaluations run in all three containers (counted per
    container from the worker name stored with each result)."""
    compose.scale("worker", 3)
    compose.wait_workers_ready(3)
    try:
        workers = [c for c in compose._containers("worker") if c.alive]
        assert len(workers) == 3
        names = {f"cmrt@{c.inspect('{{.Config.Hostname}}')}" for c in workers}
        job_id = submit(api, bend("it_scale", 0.4, popsize=12, max_evaluations=48), seed=8)
        job = wait_job(api, job_id, 240)
        assert job["status"] in ("converged", "stopped"), job
        rows = compose.sql(  # the stored worker name is cmrt@<container host name>/<pid>
            "SELECT split_part(details::json->>'worker', '/', 1), count(*) FROM evaluations "
            f"WHERE job_id = '{job_id}' AND status = 'done' GROUP BY 1 ORDER BY 1")
        per_worker = {w: int(n) for w, n in (r.split("|") for r in rows)}
        print(f"\n[--scale worker=3] evaluations per container: {per_worker}")
        assert set(per_worker) == names, (per_worker, names)
        assert all(n >= 2 for n in per_worker.values()), per_worker
        book = bookkeeping(api, job_id)
        assert sum(per_worker.values()) == book["done"] == book["expected"]
    finally:
        _two_workers(compose)


def test_compose_stop_worker_mid_generation_loses_nothing(api, compose):
    """`docker compose stop worker` (SIGTERM to every worker container) while generation 1 is
    half done (its candidate 0 held open by the delay hook): each worker finishes what it runs
    and exits cleanly; once the workers are started again the job completes with every
    evaluation stored once (repeated: at most the generation the driver sent again), and its
    result equals the same seed's uninterrupted run."""
    from test_topology import _wait_mid_generation

    job_id = submit(api, bend("it_fault_stop", 0.35, popsize=6, max_evaluations=18), seed=9)
    _wait_mid_generation(api, job_id, 1)
    t0 = time.monotonic()
    compose.compose("stop", "worker")
    stopped_in = time.monotonic() - t0
    workers = [c for c in compose._containers("worker") if c.inspect("{{.State.Status}}")]
    assert workers and not any(c.alive for c in workers)  # (removed replicas left out)
    codes = [c.inspect("{{.State.ExitCode}}") for c in workers]
    assert set(codes) == {"0"}, codes  # a warm shutdown, not the grace period's SIGKILL
    stored = sum(g["done"] for g in bookkeeping(api, job_id)["per_generation"])
    compose.compose("start", "worker")
    compose.wait_workers_ready(2)
    job = wait_job(api, job_id, 180)
    book = bookkeeping(api, job_id)
    _report("docker compose stop worker", book)
    print(f"[docker compose stop worker] stopped in {stopped_in:.1f} s; {stored} results "
          f"stored when the workers were gone; job {job['status']}")
    assert job["status"] in ("converged", "stopped"), job
    assert book["lost"] == 0 and book["failed"] == 0 and book["done"] == book["expected"]
    # the workers are gone longer than the driver's stall timeout (6 s in the tests): it sends
    # the generation's unresolved evaluations again, and those count as repeated once the
    # workers are back; at most one generation's worth
    assert book["repeated"] <= 6
    assert same_as_uninterrupted(api, job_id), "a result unlike the uninterrupted run"


def test_api_published_on_the_loopback_only(api, compose):
    """The compose file publishes the API on 127.0.0.1 (CMRT_API_BIND unset): the port answers
    there and not on this machine's other addresses."""
    api_c = next(c for c in compose._containers("api") if c.alive)
    bindings = compose.inspect_json(api_c, "{{json .HostConfig.PortBindings}}")
    assert bindings == {"8000/tcp": [{"HostIp": "127.0.0.1", "HostPort": str(compose.api_port)}]}
    assert api.get("/health").status_code == 200
    own = subprocess.run(["hostname", "-I"], capture_output=True, text=True).stdout.split()
    bridge = compose.docker("network", "inspect", "-f",
                            "{{range .IPAM.Config}}{{.Gateway}} {{end}}",
                            f"{compose.project}_default").split()
    others = [a for a in own + bridge if ":" not in a and not a.startswith("127.")]
    assert others, "no address of this machine besides the loopback"
    for addr in others:  # this machine's own addresses: nothing outside it is contacted
        with socket.socket() as s:
            s.settimeout(2)
            assert s.connect_ex((addr, compose.api_port)) != 0, f"API answers on {addr}"
    print(f"\n[api port] {bindings}; refused on {others}")
