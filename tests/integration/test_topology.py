"""The compose topology over HTTP: jobs, library, faults, bad input (see harness.py).

Every fault test prints and checks its bookkeeping: evaluations lost (stored results missing:
must be 0) and repeated (attempts beyond the first, i.e. candidates evaluated again because a
worker, the driver or the broker died under them), and that the job's result equals that of
its spec and seed run again uninterrupted (conftest.same_as_uninterrupted).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time

import pytest
from conftest import WORKER_FAULTS, bend, bookkeeping, same_as_uninterrupted, submit, wait_job

pytestmark = [pytest.mark.redis, pytest.mark.postgres]


def _report(what: str, book: dict) -> None:
    print(f"\n[{what}] expected={book['expected']} stored={book['done']} lost={book['lost']} "
          f"repeated={book['repeated']} failed={book['failed']}")


def test_jobs_converge_land_in_library_and_interpolate_and_cancel(api):
    a = submit(api, bend("it_a", 0.3, threshold=5.0))
    b = submit(api, bend("it_b", 0.5, threshold=5.0))
    c = submit(api, bend("it_long", 0.4, max_evaluations=4000, min_evaluations=4000))
    wait_job(api, c, 60, until=lambda j: j["iterations"] >= 1)
    assert api.post(f"/jobs/{c}/cancel").status_code == 202
    ja, jb, jc = wait_job(api, a), wait_job(api, b), wait_job(api, c)
    assert ja["status"] == jb["status"] == "converged", (ja, jb)
    assert jc["status"] == "cancelled" and jc["cmrt_id"] is None
    for j in (a, b):
        book = bookkeeping(api, j)
        _report(f"job {j[:8]}", book)
        assert book["lost"] == 0 and book["repeated"] == 0 and book["failed"] == 0

    found = api.get("/cmrts", params={"family": "it_bend", "duration": 0.3}).json()
    assert [c["id"] for c in found["items"]] == [ja["cmrt_id"]]
    near = api.get("/cmrts", params={"family": "it_bend", "duration": 0.48,
                                     "tolerance": 0.05}).json()
    assert [c["id"] for c in near["items"]] == [jb["cmrt_id"]]
    full = api.get(f"/cmrts/{ja['cmrt_id']}").json()
    assert full["source"]["job_id"] == a and len(full["curve"]["t"]) > 10

    mid = api.get("/cmrts/interpolate", params={"family": "it_bend", "duration": 0.4})
    assert mid.status_code == 200, mid.text
    assert {n["id"] for n in mid.json()["neighbours"]} == {ja["cmrt_id"], jb["cmrt_id"]}
    assert api.get("/cmrts/interpolate",
                   params={"family": "it_bend", "duration": 0.9}).status_code == 422
    listed = api.get("/jobs", params={"family": "it_bend", "status": "converged"}).json()
    assert {a, b} <= {j["id"] for j in listed["items"]}
    health = api.get("/health").json()
    assert health["database"] == "ok" and health["broker"] == "ok"


def _container_ip(topology, name: str) -> str:
    c = next(c for c in topology._containers(name) if c.alive)
    return c.inspect("{{range .NetworkSettings.Networks}}{{.IPAddress}}{{end}}")


def test_workers_run_on_a_host_of_their_own(topology):
    """Where namespaces can be made, every worker runs in the worker host's network namespace
    and talks to Redis and PostgreSQL across its link (the first test above ran through it).
    In compose mode every worker container is a host of its own on the compose network,
    connected to the redis and postgres containers' addresses."""
    if topology.mode == "compose":
        root = os.readlink("/proc/self/ns/net")
        redis, pg = _container_ip(topology, "redis"), _container_ip(topology, "postgres")
        workers = [c for c in topology._containers("worker") if c.alive]
        assert len(workers) >= 2
        for c in workers:
            assert os.readlink(f"/proc/{c.pid}/ns/net") != root
            links = subprocess.run(["nsenter", "-t", str(c.pid), "-n", "ss", "-tnH", "state",
                                    "established"], capture_output=True, text=True,
                                   check=True).stdout
            peers = {ln.split()[-1] for ln in links.splitlines()}
            assert f"{redis}:6379" in peers, links
        probe = ("import os, psycopg; c = psycopg.connect(os.environ['CMRT_DATABASE_URL']"
                 ".replace('+psycopg', ''), connect_timeout=10); "
                 "print(c.execute('select inet_client_addr()').fetchone()[0])")
        seen = topology.compose("exec", "-T", "--index", "1", "worker", "python", "-c",
                                probe).strip()
        ips = [c.inspect("{{range .NetworkSettings.Networks}}{{.IPAddress}}{{end}}")
               for c in workers]
        assert seen in ips, (seen, ips, pg)  # the database sees the worker container
        return
    host = getattr(topology, "worker_host", None)
    if host is None:
        pytest.skip(f"workers on the test host: {topology.worker_link_unavailable}")
    root = os.readlink("/proc/self/ns/net")
    workers = [p for p in topology.procs["worker"] if p.alive]
    assert workers and set(host.pids()) >= {p.popen.pid for p in workers}
    for p in workers:
        assert os.readlink(f"/proc/{p.popen.pid}/ns/net") != root
        assert host.host_addr in p.env["CMRT_BROKER_URL"]
        assert f"{host.host_addr}:{topology.pg_link_port}" in p.env["CMRT_DATABASE_URL"]
    links = subprocess.run(host.wrap(["ss", "-tnH", "state", "established"]),
                           capture_output=True, text=True, check=True).stdout
    peers = {ln.split()[-1] for ln in links.splitlines()}
    assert f"{host.host_addr}:{topology.redis_port}" in peers, links
    # PostgreSQL across the link, with the workers' own URL, from inside the worker host (a
    # pool process's kept connection is no proof: a cancel before this test SIGKILLs the pool
    # process running the cancelled job's candidate, and its successor has not connected yet).
    url = workers[0].env["CMRT_DATABASE_URL"].replace("postgresql+psycopg://", "postgresql://")
    probe = ("import sys, psycopg; c = psycopg.connect(sys.argv[1], connect_timeout=10); "
             "print(c.execute('select inet_client_addr()').fetchone()[0])")
    seen = subprocess.run(host.wrap([sys.executable, "-c", probe, url]), capture_output=True,
                          text=True, timeout=60, check=True).stdout.strip()
    # the forwarder's own connection arrives from loopback: the database sees the root host
    assert seen in ("127.0.0.1", "::1"), seen


def _wait_mid_generation(api, job_id, generation, timeout=90):
    """Until `generation` has at least one stored result and at least one still pending.

    For jobs named "it_fault_*" the workers hold candidate 0 of generation 1 open for
    FAULT_WINDOW_S (conftest.WORKER_FAULTS), so that state lasts seconds, not milliseconds."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        gens = api.get(f"/jobs/{job_id}/evaluations").json()["generations"]
        g = next((g for g in gens if g["generation"] == generation), None)
        if g and g["done"] >= 1 and g["pending"] >= 1:
            return g
        time.sleep(0.05)
    raise AssertionError(f"generation {generation} of job {job_id} never seen half done")


def _check_complete(api, job_id, what):
    job = wait_job(api, job_id, 180)
    assert job["status"] in ("converged", "stopped"), job
    book = bookkeeping(api, job_id)
    _report(what, book)
    assert book["lost"] == 0 and book["failed"] == 0
    assert book["done"] == book["expected"]
    gens = api.get(f"/jobs/{job_id}/generations").json()["generations"]
    assert [g["iteration"] for g in gens] == list(range(len(gens)))
    assert job["cmrt_id"] is not None
    # the fault changed when and where candidates ran, not what the job computed (in either
    # mode: the service image runs the wheel versions and the ODE build of .venv, so a
    # candidate's objective is the same bits in a worker container as in a local worker)
    assert same_as_uninterrupted(api, job_id), f"{what}: a result unlike the uninterrupted run"
    return job, book


def test_worker_kill9_mid_generation(api, topology):
    job_id = submit(api, bend("it_fault_kill_worker", 0.35, popsize=6, max_evaluations=18), seed=2)
    _wait_mid_generation(api, job_id, 1)
    t0 = time.monotonic()
    while True:  # a worker in the middle of an evaluation
        victim = next((p for p in topology.procs["worker"] if p.alive and p.busy()), None)
        if victim is not None or time.monotonic() - t0 > 30:
            break
        time.sleep(0.02)
    assert victim is not None
    victim.kill9()  # the whole worker (main process + pool child), like `docker kill`
    topology.start("worker", WORKER_FAULTS)  # compose restarts it
    _, book = _check_complete(api, job_id, "worker kill -9")
    assert book["repeated"] <= 2  # only what the killed worker was evaluating


def test_api_killed_and_restarted_resumes_from_last_generation(api, topology):
    job_id = submit(api, bend("it_fault_kill_api", 0.35, popsize=6, max_evaluations=24), seed=3)
    _wait_mid_generation(api, job_id, 1)
    before = api.get(f"/jobs/{job_id}/generations").json()["generations"]
    topology.procs["api"][-1].kill9()
    time.sleep(1.0)
    topology.start("api")  # same port; resumes the job once its driver lease expired
    job, book = _check_complete(api, job_id, "API/driver kill -9 and restart")
    after = api.get(f"/jobs/{job_id}/generations").json()["generations"]
    # stored generations were kept as they were, the job continued after them
    assert after[: len(before)] == before
    assert len(after) > len(before)
    assert book["repeated"] <= 6


def test_poison_candidate_fails_its_job_while_others_finish(api, topology):
    poison = submit(api, bend("poison", 0.3, popsize=4, max_evaluations=8), seed=4)
    healthy = submit(api, bend("it_healthy", 0.45, popsize=4, max_evaluations=8), seed=4)
    bad = wait_job(api, poison, 180)
    assert bad["status"] == "failed"
    assert "candidate 1 of generation 0" in bad["error"] and "3 times" in bad["error"], bad
    gens = api.get(f"/jobs/{poison}/evaluations").json()["generations"]
    g0 = next(g for g in gens if g["generation"] == 0)
    print(f"\n[poison] error: {bad['error']}\n[poison] generation 0: {g0}")
    assert g0["failed"] == 1
    _check_complete(api, healthy, "job next to a poison candidate")
    assert sum(p.alive for p in topology.procs["worker"]) >= 2  # workers survive their children


def test_redis_restarted_mid_job(api, topology):
    job_id = submit(api, bend("it_fault_redis", 0.35, popsize=6, max_evaluations=18), seed=5)
    _wait_mid_generation(api, job_id, 1)
    topology.stop_redis(wipe=True)  # broker gone with its queues (no persistence survives)
    time.sleep(3.0)
    topology.start_redis()
    t0 = time.monotonic()
    job = wait_job(api, job_id, 150)
    print(f"\n[redis restart] job {job['status']} {time.monotonic() - t0:.1f} s after restart")
    # a broker that comes back within CMRT_BROKER_DEADLINE costs nothing: the driver sends
    # again what the wiped queue lost, the job ends as the uninterrupted run does
    _, book = _check_complete(api, job_id, "Redis restart")
    assert book["repeated"] <= 6
    assert api.get("/health").json()["broker"] == "ok"


def test_database_connections_dropped_mid_job(api, topology):
    """Every database session of the API, its driver and the workers is terminated
    mid-generation (what a PostgreSQL restart does to them): the job carries on, nothing lost."""
    def task_failures() -> int:
        return sum(p.log.read_text(errors="replace").count("raised unexpected")
                   for p in topology.procs["worker"])

    job_id = submit(api, bend("it_fault_db_drop", 0.35, popsize=6, max_evaluations=18), seed=6)
    _wait_mid_generation(api, job_id, 1)
    failures = task_failures()
    dropped = topology.drop_database_connections()
    print(f"\n[database connections dropped] {dropped} sessions terminated")
    assert dropped >= 1
    _, book = _check_complete(api, job_id, "database connections dropped")
    assert book["repeated"] <= 6
    assert task_failures() == failures, "an evaluation task failed on the lost connection"
    assert api.get("/health").json()["database"] == "ok"


def test_the_api_answers_the_compose_names_and_refuses_a_rebound_host(api):
    """The api service as docker-compose.yml configures it (CMRT_ALLOWED_HOSTS=api): the
    name other containers use and loopback are answered; a page whose DNS name was rebound to
    the API's address is refused before any route runs, reads and writes alike."""
    for host in ("api:8000", "127.0.0.1:8000", "localhost"):
        assert api.get("/jobs", headers={"host": host}).status_code == 200, host
    rebound = {"host": "evil.example:8000", "origin": "http://evil.example:8000",
               "sec-fetch-site": "same-origin"}
    total = api.get("/jobs").json()["total"]
    for r in (api.get("/jobs", headers=rebound),
              api.post("/jobs", json={"spec": bend("it_rebound")}, headers=rebound),
              api.post("/bases", json={"family": "it_bend", "k": 1}, headers=rebound)):
        assert r.status_code == 400 and r.json()["detail"].startswith("host: "), r.text
    assert api.get("/jobs").json()["total"] == total


def test_bad_input_gets_4xx_and_stores_nothing(api):
    before = api.get("/jobs").json()["total"]
    good = bend("it_bad")
    cases = [
        (b"{not json", 400, "malformed JSON"),
        (json.dumps({"spec": {**good, "task": {"type": "juggle"}}}).encode(), 422, "task"),
        (json.dumps({"spec": {**good, "clip": {"duration": 99}}}).encode(), 422, "clip.duration"),
        (json.dumps({"spec": {**good, "optimize": {"popsize": 100000}}}).encode(), 422,
         "optimize.popsize"),
        (json.dumps({"spec": {**good, "task": {"type": "sequence", "motions": [
            {"target": {"waist": 1}, "start": 0.0, "duration": 0.1}] * 1000}}}).encode(), 422,
         "motions"),
        (b'{"name": "' + b"x" * 3_000_000 + b'"}', 413, "limit"),
    ]
    for body, status, needle in cases:
        r = api.post("/jobs", content=body, headers={"content-type": "application/json"})
        assert r.status_code == status, (needle, r.text)
        assert needle in r.json()["detail"], r.text
    assert api.get("/jobs").json()["total"] == before
    r = api.get("/cmrts", params={"family": "it_bend", "duration": "x"})
    assert r.status_code == 422 and "duration" in r.json()["detail"]


#: How long the partition drill keeps the worker host's link cut, s: longer than every timeout
#: on that link that could notice the silence: the driver's stall timeout (CMRT_STALL_TIMEOUT,
#: 6 s in conftest: it sends the unresolved evaluations again), Celery's broker connection
#: timeout (3 s), the tasks' time limits (CMRT_EVAL_TIME_LIMIT, 20 s) and kombu's check of an
#: overdue BRPOP reply (brpop_timeout 1 s + health_check_interval 25 s); shorter than the
#: driver's broker deadline (45 s), which concerns the driver's own link to Redis (not cut).
#: CMRT_IT_PARTITION_S overrides it (to try longer cuts by hand).
PARTITION_S = float(os.environ.get("CMRT_IT_PARTITION_S", "30"))
#: A job not finished this long after the link is back counts as hung, s.
RECOVERY_LIMIT_S = 90.0


def _log_since(proc, offset: int) -> str:
    return proc.log.read_text(errors="replace")[offset:]


def test_worker_link_cut_mid_generation_then_restored(api, topology):
    """Partition drill: the worker host's link is cut while generation 1 is half done (its
    candidate 0 held open by the delay hook, so a worker is mid-evaluation), kept cut for
    PARTITION_S, then restored. The job completes with every evaluation stored once (none
    lost, none failed) within RECOVERY_LIMIT_S of the restore, its result equal to the
    uninterrupted run's; it never hangs and never fails. Every worker answers a broadcast
    ping again (Celery reconnected by itself). Prints the bookkeeping, the timings and what
    the workers and the driver logged."""
    if topology.worker_link_unavailable:
        pytest.skip(f"partition drill: {topology.worker_link_unavailable}")
    workers = [p for p in topology.procs["worker"] if p.alive]
    names = topology.workers_answering(timeout=2.0)
    assert len(names) == len(workers), names
    t0 = time.monotonic()
    job_id = submit(api, bend("it_fault_partition", 0.35, popsize=6, max_evaluations=18), seed=7)
    g = _wait_mid_generation(api, job_id, 1)
    offsets = {p.name: len(p.log.read_text(errors="replace")) for p in workers}
    driver = topology.procs["api"][-1]
    driver_offset = len(driver.log.read_text(errors="replace"))
    t_cut = time.monotonic()
    topology.cut_worker_link()
    try:
        during = []  # results stored, every second of the cut
        while time.monotonic() - t_cut < PARTITION_S:
            gens = api.get(f"/jobs/{job_id}/evaluations").json()["generations"]
            during.append(sum(x["done"] for x in gens))
            time.sleep(1.0)
        answering_during = topology.workers_answering(timeout=1.0)
    finally:
        topology.restore_worker_link()
    t_restore = time.monotonic()
    job = wait_job(api, job_id, RECOVERY_LIMIT_S)
    t_end = time.monotonic()
    answering, t_ping = [], None
    while time.monotonic() - t_restore < RECOVERY_LIMIT_S:
        answering = topology.workers_answering(timeout=1.0)
        if len(answering) == len(workers):
            t_ping = time.monotonic()
            break
    logs = {p.name: _log_since(p, offsets[p.name]) for p in workers}
    driver_log = _log_since(driver, driver_offset)
    resends = driver_log.count("unresolved evaluations again")
    print(f"\n[partition] cut at generation 1 {g}; link down {t_restore - t_cut:.1f} s; "
          f"results stored during the cut {during}; workers answering a ping during the cut: "
          f"{len(answering_during)}; job {job['status']} {t_end - t_restore:.1f} s after the "
          f"restore, {t_end - t0:.1f} s after submit; all {len(workers)} workers answer a ping "
          + (f"{t_ping - t_restore:.1f} s after the restore" if t_ping else "NOT")
          + f"; the driver sent the unresolved evaluations again {resends} times")
    for name, text in logs.items():
        longest = max((float(m) for m in re.findall(r"succeeded in ([0-9.]+)s", text)),
                      default=0.0)
        counts = {what: text.count(needle) for what, needle in (
            ("tasks received", " received"), ("tasks raised", "raised unexpected"),
            ("soft limits", "Soft time limit"), ("hard limits", "Hard time limit"),
            ("pool processes lost", "exited with"), ("failed acks", "Couldn't ack"),
            ("broker connections lost", "Connection to broker lost"),
            ("(re)connections", "Connected to"))}
        notable = [ln for ln in text.splitlines() if any(k in ln for k in (
            "WARNING", "ERROR", "CRITICAL", "consumer:", "Connected"))]
        print(f"--- {name} since the cut: longest task {longest:.1f} s; "
              + ", ".join(f"{k} {v}" for k, v in counts.items()) + "; notable lines:\n"
              + "\n".join(ln[:240] for ln in notable[:10]))
    print("--- driver since the cut:\n" + "\n".join(
        ln for ln in driver_log.splitlines() if "HTTP/1.1" not in ln)[-2000:])
    assert during[0] == during[-1] == max(during), f"results stored through a cut link: {during}"
    # the link comes back: nothing lost, nothing failed, the uninterrupted run's result
    assert job["status"] in ("converged", "stopped"), job
    _, book = _check_complete(api, job_id, "worker link cut and restored")
    assert book["repeated"] <= 6
    assert t_ping is not None, f"workers answering after the restore: {answering}"
