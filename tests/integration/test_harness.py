"""The harness' compose mode against a fake `docker`, so that `make test` checks it on any
machine (`make test-compose` runs the same mode against a real engine).

The fake keeps containers in a JSON file and answers the few commands the harness uses, the
way docker compose does: `up --scale svc=N` starts stopped replicas before creating new ones,
`kill` stops, `rm` removes, `ps -a -q` lists. These tests check what the harness asks of
docker (command lines, the override file, the replica bookkeeping); the real engine's side is
not exercised here.
"""

from __future__ import annotations

import json
import os
import re
import stat
import sys
import time
from pathlib import Path

import pytest
import yaml
from harness import ComposeTopology, LocalTopology, docker_available, make_topology

FAKE = r'''
import json, os, sys
state_path, log_path = os.environ["FAKE_DOCKER_STATE"], os.environ["FAKE_DOCKER_LOG"]
args = sys.argv[1:]
with open(log_path, "a") as f:
    f.write(json.dumps(args) + "\n")
try:
    state = json.load(open(state_path))
except FileNotFoundError:
    state = {"next": 0, "containers": {}}
cs = state["containers"]

def save():
    json.dump(state, open(state_path, "w"))

def ensure(svc, n):
    mine = [c for c in cs.values() if c["service"] == svc]
    running = [c for c in mine if c["running"]]
    for c in [c for c in mine if not c["running"]][: max(0, n - len(running))]:
        c["running"] = True
        running.append(c)
    while len(running) < n:
        state["next"] += 1
        cid = f"{svc}{state['next']:012d}"
        cs[cid] = {"id": cid, "service": svc, "running": True}
        running.append(cs[cid])

if args[0] == "info":
    sys.exit(0)
if args[0] == "compose":
    i = 1
    while args[i] in ("-p", "-f"):
        i += 2
    cmd, rest = args[i], args[i + 1:]
    svc = rest[-1] if rest else None
    if cmd == "up":
        scale = [a for a in rest if "=" in a and not a.startswith("-")]
        ensure(svc, int(scale[0].split("=")[1]) if scale else 1)
    elif cmd == "ps":
        print("\n".join(c["id"] for c in cs.values() if c["service"] == svc))
    elif cmd == "kill":
        for c in cs.values():
            if c["service"] == svc:
                c["running"] = False
    elif cmd == "rm":
        stop = "-s" in rest
        for cid in [k for k, c in cs.items() if c["service"] == svc
                    and (stop or not c["running"])]:
            del cs[cid]
    elif cmd == "exec":
        print("5")
    elif cmd == "down":
        cs.clear()
elif args[0] == "inspect":
    c = cs.get(args[-1])
    if c is None:
        sys.exit(1)
    fmt = args[2]
    if "StartedAt" in fmt:
        print("2026-12-02T00:00:00Z")
    elif "Health" in fmt:
        print("healthy" if c["running"] else "unhealthy")
    else:
        print(str(c["running"]).lower())
elif args[0] == "kill":
    cs[args[-1]]["running"] = False
elif args[0] == "logs":
    print("[INFO/MainProcess] Connected\n[INFO/MainProcess] cmrt@x ready.")
save()
'''


@pytest.fixture
def fake_docker(tmp_path, monkeypatch):
    exe = tmp_path / "bin" / "docker"
    exe.parent.mkdir()
    exe.write_text(f"#!{sys.executable}\n{FAKE}")
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    log = tmp_path / "docker.log"
    monkeypatch.setenv("PATH", f"{exe.parent}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_DOCKER_STATE", str(tmp_path / "state.json"))
    monkeypatch.setenv("FAKE_DOCKER_LOG", str(log))

    def calls() -> list[list[str]]:
        return [json.loads(ln) for ln in log.read_text().splitlines()] if log.exists() else []

    return calls


def _compose_calls(calls, verb: str) -> list[list[str]]:
    out = []
    for c in calls():
        if c[0] != "compose":
            continue
        i = 1
        while c[i] in ("-p", "-f"):
            i += 2
        if c[i] == verb:
            out.append(c[i:])
    return out


def test_mode_follows_the_setting_not_the_engine(fake_docker, tmp_path, monkeypatch):
    assert docker_available()  # an engine answers, yet the default stays local
    monkeypatch.delenv("CMRT_IT_MODE", raising=False)
    local = make_topology(tmp_path / "b", {})
    assert isinstance(local, LocalTopology)
    monkeypatch.setenv("CMRT_IT_MODE", "compose")
    assert isinstance(make_topology(tmp_path / "a", {}), ComposeTopology)
    assert local.worker_host is None  # nothing made (no namespace) before it is started
    monkeypatch.setenv("CMRT_IT_MODE", "swarm")
    with pytest.raises(ValueError, match="CMRT_IT_MODE"):
        make_topology(tmp_path / "c", {})


def test_compose_session_as_the_topology_tests_drive_it(fake_docker, tmp_path):
    topo = ComposeTopology(tmp_path / "run", {"CMRT_LEASE_SECONDS": "3"})
    topo._api_ready = lambda: True  # no HTTP server behind the fake
    topo.start_redis()
    topo.create_database()
    topo.warm_up()
    faults = {"CMRT_FAULT_CRASH_ON": "poison:0:1"}
    w1 = topo.start("worker", faults)
    w2 = topo.start("worker", faults)
    api = topo.start("api")
    topo.wait_workers_ready(2)

    # every compose call names the private project, the compose file and the override file
    assert topo.compose_cmd == ["docker", "compose"]  # v2 answers `docker compose version`
    for c in fake_docker():
        if c[0] == "compose" and c[1] != "version":
            assert c[1:3] == ["-p", topo.project] and c[3:5] == ["-f", str(Path(
                "docker-compose.yml").resolve())] and c[5:7] == ["-f", str(topo.override_file)]
    override = yaml.safe_load(topo.override_file.read_text())["services"]
    assert override["worker"]["environment"] == {"CMRT_LEASE_SECONDS": "3", **faults}
    assert override["api"]["environment"] == {"CMRT_LEASE_SECONDS": "3"}
    assert override["api"]["healthcheck"] == {"interval": "2s"}  # compose's checks, sooner
    ups = _compose_calls(fake_docker, "up")
    assert ups[0][-1] == "redis" and "--no-deps" in ups[0]
    assert ups[1][-1] == "postgres" and "--no-deps" in ups[1]
    assert re.fullmatch(r"cmrt-it-\d+-[0-9a-f]{8}", topo.project)
    assert [u[-2:] for u in ups[2:]] == [["worker=1", "worker"], ["worker=2", "worker"],
                                         ["api=1", "api"]]
    assert all("--no-deps" in u and "--no-recreate" in u for u in ups[2:])
    assert _compose_calls(fake_docker, "build") == [["build", "api"]]
    assert len({w1.id, w2.id}) == 2 and w1.alive and w2.alive and api.alive
    assert topo.url("/health") == f"http://127.0.0.1:{topo.api_port}/health"

    # a killed worker is brought back (the stopped replica is started again, not a third one)
    w1.kill9()
    assert not w1.alive and ["kill", "-s", "KILL", w1.id] in fake_docker()
    again = topo.start("worker", faults)
    assert again is w1 and w1.alive
    assert [c.id for c in topo.procs["worker"]] == [w1.id, w2.id]
    assert "ready." in w2.log.read_text() and not w2.busy()

    # the api killed and restarted; never a second API replica (it publishes the port)
    topo.procs["api"][-1].kill9()
    assert topo.start("api") is api and api.alive
    assert topo.start("api") is api
    assert [u[-2:] for u in _compose_calls(fake_docker, "up")][-1] == ["api=1", "api"]

    # redis killed and wiped, then up again; database sessions dropped
    old_redis = topo.procs["redis"][0].id
    topo.stop_redis(wipe=True)
    assert _compose_calls(fake_docker, "kill")[-1] == ["kill", "-s", "KILL", "redis"]
    assert _compose_calls(fake_docker, "rm")[-1] == ["rm", "-f", "-s", "redis"]
    assert ["volume", "rm", "-f", f"{topo.project}_redisdata"] in fake_docker()
    topo.start_redis()
    assert [c.id for c in topo.procs["redis"] if c.alive] != [old_redis]  # a fresh container
    assert topo.drop_database_connections() == 5
    psql = _compose_calls(fake_docker, "exec")[-1]
    assert psql[:4] == ["exec", "-T", "postgres", "psql"] and "pg_terminate_backend" in psql[-1]

    topo.stop_all()
    assert _compose_calls(fake_docker, "down")[-1][:2] == ["down", "-v"]


# -- the worker host (network namespace) and the PostgreSQL forwarder, for real ---------------

def _needs_netns():
    from harness import netns_unavailable

    reason = netns_unavailable()
    if reason:
        pytest.skip(reason)


def _echo_server(host: str):
    """A one-connection-at-a-time echo server on (host, free port), in a thread."""
    import socket
    import threading

    srv = socket.socket()
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind((host, 0))
    srv.listen()

    def serve():
        while True:
            try:
                c, _ = srv.accept()
            except OSError:
                return
            with c:
                while data := c.recv(4096):
                    c.sendall(data)

    threading.Thread(target=serve, daemon=True).start()
    return srv


def _run_in(host, code: str, timeout: float = 20) -> str:
    import subprocess

    r = subprocess.run(host.wrap([sys.executable, "-c", code]), capture_output=True, text=True,
                       timeout=timeout)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip()


def test_worker_host_link_forwarder_cut_restore_and_cleanup(tmp_path):
    """A NetnsHost reaches the root namespace only at its link's root side; the forwarder there
    carries a connection to a server on the root loopback; a cut silences an established
    connection and refuses new ones; a restore brings both back; destroy leaves nothing."""
    import subprocess

    from harness import NetnsHost, Proc, free_port

    _needs_netns()
    host = NetnsHost.create()
    srv = _echo_server("127.0.0.1")
    fwd = None
    try:
        assert host.name in subprocess.run(["ip", "netns", "list"], capture_output=True,
                                           text=True).stdout
        port = free_port(host.host_addr)
        fwd = Proc("fwd", [sys.executable, str(Path(__file__).with_name("tcp_forward.py")),
                           host.host_addr, str(port), "127.0.0.1",
                           str(srv.getsockname()[1])], dict(os.environ), tmp_path / "fwd.log")
        fwd.start()
        for _ in range(100):
            if "listening" in fwd.tail(5):
                break
            import time

            time.sleep(0.05)
        connect = (f"import socket; s = socket.create_connection(({host.host_addr!r}, {port}), "
                   "timeout=3); s.sendall(b'ping'); print(s.recv(4).decode())")
        assert _run_in(host, connect) == "ping"  # through the link and the forwarder
        loopback = ("import socket\ntry:\n socket.create_connection(('127.0.0.1', "
                    f"{srv.getsockname()[1]}), timeout=2); print('reached')\n"
                    "except OSError: print('refused')")
        assert _run_in(host, loopback) == "refused"  # the root loopback is another host's

        # an established connection across a cut: silent while cut, alive after the restore
        code = f"""
import socket, sys
s = socket.create_connection(({host.host_addr!r}, {port}), timeout=3)
s.sendall(b'a'); assert s.recv(1) == b'a'
print('up', flush=True); sys.stdin.readline()          # the link is cut now
s.settimeout(1.5); s.sendall(b'b')
try:
    s.recv(1); print('answered', flush=True)
except TimeoutError:
    print('silent', flush=True)
try:
    socket.create_connection(({host.host_addr!r}, {port}), timeout=2); print('connected')
except OSError as err:
    print('no new connection', flush=True)
sys.stdin.readline()                                    # restored
s.settimeout(10); print('late answer', s.recv(1).decode(), flush=True)
"""
        p = subprocess.Popen(host.wrap([sys.executable, "-c", code]), stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
        assert p.stdout.readline().strip() == "up"
        host.cut()
        assert not host.link_up
        p.stdin.write("\n")
        p.stdin.flush()
        assert p.stdout.readline().strip() == "silent"
        assert p.stdout.readline().strip() == "no new connection"
        host.restore()
        assert host.link_up
        p.stdin.write("\n")
        p.stdin.flush()
        assert p.stdout.readline().strip() == "late answer b"  # TCP retransmitted it
        assert p.wait(timeout=10) == 0
    finally:
        if fwd is not None:
            fwd.stop()
        srv.close()
        host.destroy()
    listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    assert host.name not in listed
    links = subprocess.run(["ip", "-br", "link"], capture_output=True, text=True).stdout
    assert host.host_if not in links


def test_stale_worker_hosts_of_dead_runs_are_swept():
    """A namespace named after a test process that is gone (a run killed before its finalizers)
    is removed, with what runs in it, by the next NetnsHost.create; live runs' are kept."""
    import subprocess

    from harness import NETNS_PREFIX, NetnsHost, sweep_stale_netns

    _needs_netns()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = f"{NETNS_PREFIX}{dead.pid}-0badc0"
    live = NetnsHost.create()  # named after this (live) process
    subprocess.run(["ip", "netns", "add", stale], check=True)
    sleeper = subprocess.Popen(["ip", "netns", "exec", stale, "sleep", "60"])
    try:
        # `ip netns exec` enters the namespace after it starts: sweep once the sleeper is in it
        deadline = time.monotonic() + 30
        while not subprocess.run(["ip", "netns", "pids", stale], capture_output=True,
                                 text=True).stdout.strip():
            assert time.monotonic() < deadline, "the sleeper never entered its namespace"
            time.sleep(0.05)
        removed = sweep_stale_netns()
        assert stale in removed and live.name not in removed
        assert sleeper.wait(timeout=10) != 0  # killed with its namespace
        listed = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
        assert stale not in listed and live.name in listed
    finally:
        sleeper.kill()
        subprocess.run(["ip", "netns", "del", stale], capture_output=True)
        live.destroy()


def test_worker_host_unavailable_gives_a_reason(monkeypatch, tmp_path):
    """Without root, without `ip`, or turned off, the reason the partition drill skips with."""
    import harness

    monkeypatch.setenv("CMRT_IT_NETNS", "0")
    assert "CMRT_IT_NETNS=0" in harness.netns_unavailable()
    monkeypatch.delenv("CMRT_IT_NETNS")
    monkeypatch.setattr(harness.shutil, "which", lambda name: None)
    assert "`ip` (iproute2) not found" in harness.netns_unavailable()
    monkeypatch.setattr(harness.shutil, "which", lambda name: f"/usr/sbin/{name}")
    monkeypatch.setattr(harness.os, "geteuid", lambda: 1000)
    assert "not root" in harness.netns_unavailable()
    topo = LocalTopology(tmp_path / "run", netns=False)
    assert topo.worker_host is None and "netns=False" in topo.worker_link_unavailable
