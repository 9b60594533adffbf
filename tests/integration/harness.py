"""Starts the services that docker-compose.yml names, for the topology tests.

`make_topology(workdir, overrides)` picks the mode: CMRT_IT_MODE = local (the default, what
`make test` runs, engine or not) | compose (what `make test-compose` runs; needs an engine).
Both modes offer the same interface (`BaseTopology`), which is all the tests use.

compose (`ComposeTopology`): `docker compose` runs the file itself, as a private project
  (`cmrt-it-<random>`), with a generated override file that adds the tests' settings (short
  timeouts, fault hooks of the workers) to the api and worker services and publishes the API on
  a free port. A service replica is a container: `kill9` is `docker kill -s KILL`, a restart is
  `docker compose up -d --no-recreate`, Redis is wiped by removing its volume, and the database
  sessions are terminated through `psql` in the postgres container. `stop_all` is
  `docker compose down -v`. This mode needs an engine (`make test-compose` installs and starts
  one, scripts/docker-engine.sh); test_harness.py also checks its command lines against a fake
  `docker`, so that `make test` covers them on a machine without an engine.
local (`LocalTopology`): each application service's own `command` and `environment` from the
  compose file run as local processes (in their own process group, so `kill -9` takes the whole
  service like a container dying), against:
  - redis:    the compose service's command run locally by `redis-server` on a free port
              (a private instance, so the tests may restart it without touching anyone else's);
  - postgres: the machine's PostgreSQL server (CMRT_IT_PG, default
              postgresql+psycopg://postgres@127.0.0.1:5432/test) with a fresh database per run.
  Host names in the compose URLs (redis, postgres) are rewritten to these local addresses; the
  `python` of the commands is this interpreter. Logs go to the run's temporary folder.
  Where network namespaces can be made (`netns_unavailable()` says why not), the workers run
  on a host of their own (`NetnsHost`: a namespace and a veth link) and reach Redis (also bound
  to the link's root side) and PostgreSQL (through tcp_forward.py on the link's root side) only
  across that link, which `cut_worker_link()` / `restore_worker_link()` cut and restore.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import yaml

from worker import faults

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = ROOT / "docker-compose.yml"
PG_ADMIN_URL = os.environ.get("CMRT_IT_PG", "postgresql+psycopg://postgres@127.0.0.1:5432/test")


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def sa_url(url: str):
    """`url` parsed by SQLAlchemy (host, port, database, `set(...)`)."""
    import sqlalchemy as sa

    return sa.engine.make_url(url)


_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::?-([^}]*))?\}")


def interpolate(value: str, env: dict[str, str]) -> str:
    """Compose-style ${VAR:-default} substitution."""
    return _VAR.sub(lambda m: env.get(m.group(1)) or (m.group(2) or ""), str(value))


def docker_available() -> bool:
    if shutil.which("docker") is None:
        return False
    try:
        return subprocess.run(["docker", "info"], capture_output=True, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


#: Where the worker hosts' links are numbered: one /30 per link (host side .1, worker side .2),
#: a random one per run among those no interface of the machine uses.
NETNS_NET = "10.231"
#: Network namespaces of this harness are named `cmrt-it-<pid of the test process>-<random>`;
#: one whose process is gone is a leftover of a killed run, removed by the next run.
NETNS_PREFIX = "cmrt-it-"


def netns_unavailable() -> str | None:
    """Why worker hosts (network namespaces) cannot be made here, or None if they can."""
    if os.environ.get("CMRT_IT_NETNS", "1") in ("0", "off", "no"):
        return "CMRT_IT_NETNS=0: workers run in the root network namespace"
    if sys.platform != "linux":
        return f"network namespaces are a Linux feature (platform {sys.platform})"
    if shutil.which("ip") is None:
        return "`ip` (iproute2) not found: cannot make a network namespace for the worker host"
    if os.geteuid() != 0:
        return "not root: `ip netns add` and veth links need CAP_NET_ADMIN"
    probe = f"{NETNS_PREFIX}probe-{os.getpid()}"
    r = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if r.returncode != 0:
        return f"`ip netns add` failed: {r.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


def _ip(*args: str, netns: str | None = None, netns_pid: int | None = None,
        check: bool = True) -> str:
    """`ip ARGS` here, in the named namespace `netns`, or in the network namespace of the
    process `netns_pid` (a container's)."""
    argv = ["ip", *args]
    if netns:
        argv = ["ip", "netns", "exec", netns, *argv]
    elif netns_pid:
        argv = ["nsenter", "-t", str(netns_pid), "-n", *argv]
    r = subprocess.run(argv, capture_output=True, text=True, timeout=30)
    if check and r.returncode != 0:
        raise RuntimeError(f"{' '.join(argv)} failed ({r.returncode}): {r.stderr.strip()}")
    return r.stdout


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_stale_netns() -> list[str]:
    """Remove the worker hosts left by runs whose test process is gone (killed before its
    finalizers ran): their processes are killed, the namespace deleted (which deletes its veth
    pair). Returns the names removed."""
    removed = []
    for line in _ip("netns", "list", check=False).splitlines():
        name = line.split()[0] if line.split() else ""
        m = re.fullmatch(re.escape(NETNS_PREFIX) + r"(?:probe-)?(\d+)(?:-[0-9a-f]+)?", name)
        if m is None or _pid_alive(int(m.group(1))):
            continue
        NetnsHost(name, "", "", "", "").destroy()
        removed.append(name)
    return removed


@dataclass
class NetnsHost:
    """A separate "host" for services: a network namespace joined to the root namespace by a
    veth pair, `host_addr` (root side) <-> `addr` (namespace side), one /30 of NETNS_NET.

    What runs inside (`wrap(argv)`: `ip netns exec NAME argv`, the same process, so its pid and
    process group are the service's own) reaches the root namespace only at `host_addr`, where
    the harness exposes Redis and PostgreSQL. `cut()` sets the root side of the link down: the
    namespace's packets are dropped without an answer (its link has no carrier), and the root
    side's replies have no route, so to the worker the servers fall silent without a reset or
    a FIN, like a dead switch port or a partition; `restore()` brings it back (same addresses,
    so established TCP connections may survive a short cut). `destroy()` kills whatever still
    runs inside and deletes the namespace and the link.
    """

    name: str
    host_if: str
    ns_if: str
    host_addr: str
    addr: str

    @classmethod
    def create(cls) -> NetnsHost:
        sweep_stale_netns()
        tag = uuid.uuid4().hex[:6]
        used = _ip("-4", "-o", "addr", check=False)
        for _ in range(100):
            a, b = uuid.uuid4().bytes[:2]
            net = f"{NETNS_NET}.{a}"
            first = b & 0xFC  # the /30's network address
            if not any(f" {net}.{first + k}/" in used for k in range(4)):
                break
        else:  # pragma: no cover
            raise RuntimeError(f"no free /30 in {NETNS_NET}.0.0/16")
        host = cls(f"{NETNS_PREFIX}{os.getpid()}-{tag}", f"ci{tag}h", f"ci{tag}n",
                   f"{net}.{first + 1}", f"{net}.{first + 2}")
        try:
            _ip("netns", "add", host.name)
            _ip("link", "add", host.host_if, "type", "veth", "peer", "name", host.ns_if)
            _ip("link", "set", host.ns_if, "netns", host.name)
            _ip("addr", "add", f"{host.host_addr}/30", "dev", host.host_if)
            _ip("link", "set", host.host_if, "up")
            _ip("addr", "add", f"{host.addr}/30", "dev", host.ns_if, netns=host.name)
            _ip("link", "set", host.ns_if, "up", netns=host.name)
            _ip("link", "set", "lo", "up", netns=host.name)
        except BaseException:
            host.destroy()
            raise
        return host

    def wrap(self, argv: list[str]) -> list[str]:
        return ["ip", "netns", "exec", self.name, *argv]

    def cut(self) -> None:
        _ip("link", "set", self.host_if, "down")

    def restore(self) -> None:
        _ip("link", "set", self.host_if, "up")

    @property
    def link_up(self) -> bool:
        return "UP" in _ip("-br", "link", "show", self.host_if, check=False).split()[1:2]

    def pids(self) -> list[int]:
        out = _ip("netns", "pids", self.name, check=False)
        return [int(p) for p in out.split()]

    def destroy(self) -> None:
        for pid in self.pids():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        _ip("netns", "del", self.name, check=False)
        if self.host_if:  # normally gone with its peer; not if the peer never moved in
            _ip("link", "del", self.host_if, check=False)


@dataclass
class Proc:
    name: str
    argv: list[str]
    env: dict[str, str]
    log: Path
    popen: subprocess.Popen | None = None

    def start(self) -> None:
        fh = open(self.log, "ab")  # noqa: SIM115 - owned by the child
        fh.write(f"\n=== start {' '.join(self.argv)} ===\n".encode())
        fh.flush()
        self.popen = subprocess.Popen(self.argv, env=self.env, cwd=ROOT, stdout=fh,
                                      stderr=subprocess.STDOUT, start_new_session=True)

    @property
    def alive(self) -> bool:
        return self.popen is not None and self.popen.poll() is None

    def kill9(self) -> None:
        """SIGKILL the whole process group (the service and its children), like a container
        being killed."""
        if self.popen is None:
            return
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.popen.pid, signal.SIGKILL)
        self.popen.wait(timeout=10)

    def stop(self) -> None:
        if not self.alive:
            return
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.popen.pid, signal.SIGTERM)
        try:
            self.popen.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.kill9()

    def tail(self, n: int = 40) -> str:
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""

    def busy(self) -> bool:
        """True if the worker's log shows a task received and not finished yet."""
        return _busy(self.tail(20))

    def children(self) -> list[int]:
        """Pids of this service's processes other than the leader (e.g. Celery pool children)."""
        if self.popen is None:
            return []
        out = subprocess.run(["pgrep", "-g", str(self.popen.pid)], capture_output=True, text=True)
        return [int(p) for p in out.stdout.split() if int(p) != self.popen.pid]


class BaseTopology:
    """What the topology tests use; one implementation per mode (see module docstring).

    Contract:
      * `procs[name]`: the replicas of service `name` ever started, oldest first, each with
        `name`, `alive`, `busy()` (a worker whose log shows a task received and not finished),
        `kill9()` (SIGKILL to the whole replica, like a container killed), `stop()`,
        `tail(n)` and `log` (a Path holding the replica's log so far);
      * `start_redis()` / `stop_redis(wipe)`: the broker up (healthy) / killed, with its data
        gone when `wipe`;
      * `create_database()` / `drop_database()` / `drop_database_connections()` (terminates
        every session of the application's database and returns how many);
      * `warm_up()`: whatever makes the first evaluations not pay a one-off cost;
      * `start(name, extra)`: one more running replica of an application service (api,
        worker) with `extra` environment variables; returns it once started (the api: once
        /health answers);
      * `wait_workers_ready(count)`, `url(path)` of the API, `logs()`, `stop_all()`;
      * the workers' network link: `worker_link_unavailable` (None where the workers run on a
        host of their own whose link the tests can cut, else why not: the partition drill
        skips with that reason), `cut_worker_link()` (from then on the workers' packets to and
        from Redis and PostgreSQL vanish without an answer) and `restore_worker_link()`.
    """

    procs: dict
    worker_link_unavailable: str | None = "this topology cannot cut the workers' link"

    def cut_worker_link(self) -> None:
        raise NotImplementedError(self.worker_link_unavailable)

    def restore_worker_link(self) -> None:
        raise NotImplementedError(self.worker_link_unavailable)

    def start_redis(self) -> None:
        raise NotImplementedError

    def stop_redis(self, wipe: bool = False) -> None:
        raise NotImplementedError

    def create_database(self) -> None:
        raise NotImplementedError

    def drop_database(self) -> None:
        raise NotImplementedError

    def drop_database_connections(self) -> int:
        raise NotImplementedError

    def warm_up(self) -> None:
        raise NotImplementedError

    def start(self, name: str, extra: dict[str, str] | None = None):
        raise NotImplementedError

    def wait_workers_ready(self, count: int, timeout: float = 60) -> None:
        raise NotImplementedError

    def url(self, path: str) -> str:
        raise NotImplementedError

    def logs(self) -> str:
        raise NotImplementedError

    def stop_all(self) -> None:
        raise NotImplementedError

    def _wait(self, ok, what: str, timeout: float, proc=None) -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if ok():
                return
            if proc is not None and not proc.alive:
                raise RuntimeError(f"{what} exited:\n{proc.tail()}")
            time.sleep(0.2)
        raise RuntimeError(f"{what} not ready after {timeout} s:\n"
                           + (proc.tail() if proc else ""))

    def _api_ready(self) -> bool:
        try:
            return httpx.get(self.url("/health"), timeout=2).status_code == 200
        except httpx.HTTPError:
            return False


def _busy(tail: str) -> bool:
    """True if a worker log's tail shows a task received and not finished yet."""
    lines = [ln for ln in tail.splitlines() if "Task cmrt." in ln]
    return bool(lines) and lines[-1].rstrip().endswith("received")


@dataclass
class LocalTopology(BaseTopology):
    """The compose topology as local processes (see module docstring)."""

    workdir: Path
    overrides: dict[str, str] = field(default_factory=dict)
    compose: dict = field(default_factory=dict)
    procs: dict[str, list[Proc]] = field(default_factory=dict)
    redis_port: int = 0
    api_port: int = 0
    database: str = ""
    database_url: str = ""
    mode: str = "local"
    #: Run the workers on a host of their own (a network namespace) where one can be made.
    netns: bool = True
    worker_host: NetnsHost | None = None
    worker_link_unavailable: str | None = None
    pg_link_port: int = 0

    def __post_init__(self) -> None:
        self.compose = yaml.safe_load(COMPOSE.read_text())
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.worker_link_unavailable = (netns_unavailable() if self.netns else
                                        "LocalTopology(netns=False): workers on this host")

    # -- the workers' host -------------------------------------------------------------------
    def _ensure_worker_host(self) -> None:
        """Made with the first service (start_redis), not by the constructor, so that a
        topology never started leaves nothing behind; stop_all deletes it."""
        if self.worker_host is None and self.worker_link_unavailable is None:
            self.worker_host = NetnsHost.create()

    def _start_pg_link(self) -> None:
        """The worker host's way to PostgreSQL: a forwarder on the link's root side
        (tcp_forward.py), since the server listens on the root namespace's loopback only."""
        h = self.worker_host
        if h is None or "pg-link" in self.procs:
            return
        target = sa_url(PG_ADMIN_URL)
        self.pg_link_port = self.pg_link_port or free_port(h.host_addr)
        argv = [sys.executable, str(Path(__file__).with_name("tcp_forward.py")), h.host_addr,
                str(self.pg_link_port), target.host or "127.0.0.1", str(target.port or 5432)]
        p = Proc("pg-link", argv, dict(os.environ), self.workdir / "pg-link.log")
        p.start()
        self.procs["pg-link"] = [p]
        self._wait(lambda: "listening" in p.tail(5), "pg-link forwarder", 15, p)

    def workers_answering(self, timeout: float = 1.0) -> list[str]:
        """Node names of the Celery workers that answer a broadcast ping now (sent from the
        root namespace: a worker answers only once its broker connection works again).

        In a child process: a Celery app used in the test process leaves connections that
        multiprocessing's after-fork hooks close in every forked child, and two children
        closing the same inherited socket can hang (the store's fork tests did)."""
        code = ("import json, sys; from celery import Celery; "
                "app = Celery('cmrt-it-ping', broker=sys.argv[1]); "
                "print(json.dumps(app.control.ping(timeout=float(sys.argv[2]))))")
        r = subprocess.run([sys.executable, "-c", code, f"redis://127.0.0.1:{self.redis_port}/0",
                            str(timeout)], capture_output=True, text=True, timeout=60 + timeout)
        if r.returncode != 0:
            raise RuntimeError(f"celery ping failed: {r.stderr[-2000:]}")
        return sorted(name for reply in json.loads(r.stdout) for name in reply)

    def cut_worker_link(self) -> None:
        if self.worker_host is None:
            raise RuntimeError(self.worker_link_unavailable)
        self.worker_host.cut()

    def restore_worker_link(self) -> None:
        if self.worker_host is None:
            raise RuntimeError(self.worker_link_unavailable)
        self.worker_host.restore()

    # -- infrastructure ----------------------------------------------------------------------
    def _service(self, name: str) -> dict:
        return self.compose["services"][name]

    def start_redis(self) -> None:
        argv = [interpolate(a, {}) for a in self._service("redis")["command"]]
        if not shutil.which(argv[0]):
            raise RuntimeError(f"{argv[0]} not found: install redis-server for the topology tests")
        self._ensure_worker_host()
        self.redis_port = self.redis_port or free_port()
        data = self.workdir / "redis"
        data.mkdir(exist_ok=True)
        bind = ["127.0.0.1"] + ([self.worker_host.host_addr] if self.worker_host else [])
        argv += ["--port", str(self.redis_port), "--bind", *bind, "--dir", str(data),
                 "--save", ""]
        if self.worker_host:  # reachable only from loopback and the worker host's private link
            argv += ["--protected-mode", "no"]
        p = Proc("redis", argv, dict(os.environ), self.workdir / "redis.log")
        p.start()
        self.procs["redis"] = [p]
        self._wait(lambda: _redis_ping(self.redis_port), "redis", 15)

    def stop_redis(self, wipe: bool = False) -> None:
        for p in self.procs.pop("redis", []):
            p.kill9()
        if wipe:
            shutil.rmtree(self.workdir / "redis", ignore_errors=True)

    def create_database(self) -> None:
        import sqlalchemy as sa

        self.database = f"cmrt_it_{uuid.uuid4().hex[:10]}"
        admin = sa.create_engine(PG_ADMIN_URL, isolation_level="AUTOCOMMIT")
        with admin.connect() as c:
            c.execute(sa.text(f'CREATE DATABASE "{self.database}"'))
        admin.dispose()
        self.database_url = PG_ADMIN_URL.rsplit("/", 1)[0] + "/" + self.database
        from store import init_db

        init_db(self.database_url).dispose()
        self._start_pg_link()

    def drop_database_connections(self) -> int:
        """Terminate every session of the test database, as a PostgreSQL restart does to its
        clients (the server itself, shared with others, stays up). Returns how many."""
        import sqlalchemy as sa

        admin = sa.create_engine(PG_ADMIN_URL, isolation_level="AUTOCOMMIT")
        with admin.connect() as c:
            n = c.execute(sa.text(
                "SELECT count(pg_terminate_backend(pid)) FROM pg_stat_activity "
                "WHERE datname = :db AND pid <> pg_backend_pid()"), {"db": self.database}).scalar()
        admin.dispose()
        return int(n or 0)

    def drop_database(self) -> None:
        if not self.database:
            return
        import sqlalchemy as sa

        admin = sa.create_engine(PG_ADMIN_URL, isolation_level="AUTOCOMMIT")
        with admin.connect() as c:
            c.execute(sa.text(f'DROP DATABASE IF EXISTS "{self.database}" WITH (FORCE)'))
        admin.dispose()

    # -- application services ----------------------------------------------------------------
    def env_for(self, name: str, extra: dict[str, str] | None = None) -> dict[str, str]:
        env = dict(os.environ)
        for k in faults.ENV_VARS:
            env.pop(k, None)
        for k, v in (self._service(name).get("environment") or {}).items():
            env[k] = interpolate(v, {**self.overrides})
        across = name == "worker" and self.worker_host is not None
        redis_host = self.worker_host.host_addr if across else "127.0.0.1"
        redis = f"redis://{redis_host}:{self.redis_port}"
        for k, v in list(env.items()):
            if isinstance(v, str) and "redis://redis:6379" in v:
                env[k] = v.replace("redis://redis:6379", redis)
        env["CMRT_DATABASE_URL"] = self.database_url
        if across:  # PostgreSQL through the forwarder on the link's root side
            url = sa_url(self.database_url)
            env["CMRT_DATABASE_URL"] = url.set(host=self.worker_host.host_addr,
                                               port=self.pg_link_port).render_as_string(
                                                   hide_password=False)
        env.update(self.overrides)
        env.update(extra or {})
        env.pop("NUMBA_CACHE_DIR", None)  # use the checkout's warm cache (see warm_up)
        env["PYTHONUNBUFFERED"] = "1"
        env["CMRT_DATA_DIR"] = str(self.workdir / "data")
        return env

    def argv_for(self, name: str, env: dict[str, str]) -> list[str]:
        argv = [interpolate(a, env) for a in self._service(name)["command"]]
        if argv[0] in ("python", "python3"):
            argv[0] = sys.executable
        if name == "api":
            self.api_port = self.api_port or free_port()
            argv = _set_opt(argv, "--port", str(self.api_port))
            argv = _set_opt(argv, "--host", "127.0.0.1")
        return argv

    def start(self, name: str, extra: dict[str, str] | None = None) -> Proc:
        env = self.env_for(name, extra)
        n = len(self.procs.get(name, []))
        p = Proc(f"{name}-{n}", self.argv_for(name, env), env, self.workdir / f"{name}-{n}.log")
        if name == "worker":
            p.argv += ["--hostname", f"worker{n}-{uuid.uuid4().hex[:4]}@%h"]
            if self.worker_host is not None:
                p.argv = self.worker_host.wrap(p.argv)
        p.start()
        self.procs.setdefault(name, []).append(p)
        if name == "api":
            self._wait(self._api_ready, "api", 60, p)
        return p

    def warm_up(self) -> None:
        """Compile/load the simulator's numba cache once, before workers time anything."""
        subprocess.run([sys.executable, "-c", *WARM_UP], cwd=ROOT, check=True,
                       env=self.env_for("worker"), timeout=600)

    def wait_workers_ready(self, count: int, timeout: float = 60) -> None:
        """Until `count` worker processes logged that they are ready."""
        def ready() -> bool:
            n = 0
            for p in self.procs.get("worker", []):
                last_run = p.log.read_text(errors="replace").split("=== start")[-1]
                if p.alive and " ready." in last_run:
                    n += 1
            return n >= count
        self._wait(ready, f"{count} workers", timeout)

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.api_port}{path}"

    def stop_all(self) -> None:
        for name in ("api", "worker", "pg-link"):
            for p in self.procs.get(name, []):
                p.stop()
        self.stop_redis()
        if self.worker_host is not None:
            self.worker_host.destroy()
            self.worker_host = None

    def logs(self) -> str:
        return "\n".join(f"--- {p.name} ---\n{p.tail(60)}"
                         for ps in self.procs.values() for p in ps)


#: `python -c` arguments that compile the simulator's numba kernels into the cache of the
#: machine or container it runs on (a quiet stance of 0.1 s), so that no worker's first
#: evaluation pays that (tens of seconds on a loaded machine: past the tests' time limit).
WARM_UP = ["from sim.spec import parse_spec; from optim.objective import SimObjective; "
           "from optim.spline import flat_params; import json, sys; "
           "s = parse_spec(json.loads(sys.argv[1])); SimObjective(s)(flat_params(s))",
           json.dumps({"name": "warm", "task": {"type": "quiet_stance"},
                       "clip": {"preparation": 0.0, "duration": 0.1, "decay": 0.0}})]

#: Application services whose environment the override file extends.
APP_SERVICES = ("api", "worker")
#: The compose file's health checks, run more often for the tests (the file's intervals, 10 s
#: and 30 s, are for production; Docker 20.10 has no start_interval). Readiness in compose
#: mode is what these report (`docker inspect` .State.Health).
TEST_HEALTHCHECKS = {"api": {"interval": "2s"}, "worker": {"interval": "4s"},
                     "redis": {"interval": "1s"}, "postgres": {"interval": "1s"}}
#: Compose projects of this harness are named `cmrt-it-<pid of the test process>-<random>`;
#: one whose process is gone is a leftover of a killed run, removed by the next run.
PROJECT_RE = re.compile(r"cmrt-it-(\d+)-[0-9a-f]+")


def compose_command(docker: str = "docker") -> list[str]:
    """The compose command of this machine: `docker compose` (v2) where that plugin answers,
    else `docker-compose` (v1, Debian's). Both take the same options the harness uses."""
    try:
        if subprocess.run([docker, "compose", "version"], capture_output=True,
                          timeout=30).returncode == 0:
            return [docker, "compose"]
    except (OSError, subprocess.TimeoutExpired):
        pass
    if shutil.which("docker-compose"):
        return ["docker-compose"]
    raise RuntimeError("compose mode needs `docker compose` (v2) or `docker-compose` (v1); "
                       "scripts/docker-engine.sh installs one")


class Container:
    """One replica of a compose service (a container), with `Proc`'s interface."""

    def __init__(self, topo: ComposeTopology, name: str, cid: str) -> None:
        self.topo = topo
        self.name = name
        self.id = cid

    def inspect(self, fmt: str) -> str:
        return self.topo.docker("inspect", "-f", fmt, self.id, check=False).strip()

    @property
    def alive(self) -> bool:
        return self.inspect("{{.State.Running}}") == "true"

    @property
    def health(self) -> str:
        """What the compose file's health check says: healthy, unhealthy, starting, or ""."""
        return self.inspect("{{if .State.Health}}{{.State.Health.Status}}{{end}}")

    @property
    def pid(self) -> int:
        """The container's main process as this machine sees it (0 if not running)."""
        return int(self.inspect("{{.State.Pid}}") or 0)

    def kill9(self) -> None:
        self.topo.docker("kill", "-s", "KILL", self.id, check=False)
        deadline = time.monotonic() + 10.0  # `docker kill` returns once the signal is sent
        while self.alive and time.monotonic() < deadline:
            time.sleep(0.1)

    def stop(self) -> None:
        self.topo.docker("stop", self.id, check=False)

    def tail(self, n: int = 40) -> str:
        return self.topo.docker("logs", "--tail", str(n), self.id, check=False, stderr=True)

    @property
    def log(self) -> Path:
        path = self.topo.workdir / f"{self.name}.log"
        path.write_text(self.topo.docker("logs", self.id, check=False, stderr=True))
        return path

    def busy(self) -> bool:
        return _busy(self.tail(20))

    def ready(self) -> bool:
        """Running, healthy by the compose file's check, and its Celery worker said "ready"
        since its last start (a health check passed before a restart is not enough)."""
        if not self.alive or self.health != "healthy":
            return False
        started = self.inspect("{{.State.StartedAt}}")
        return " ready." in self.topo.docker("logs", "--since", started, self.id, check=False,
                                             stderr=True)


def sweep_stale_projects(topo: ComposeTopology) -> list[str]:
    """`down -v` the compose projects left by runs whose test process is gone (killed before
    their finalizers ran): their containers, networks and volumes. Returns the names removed."""
    out = topo.docker("ps", "-a", "--filter", "label=com.docker.compose.project",
                      "--format", '{{.Label "com.docker.compose.project"}}', check=False)
    out += topo.docker("volume", "ls", "--filter", "label=com.docker.compose.project",
                       "--format", '{{.Label "com.docker.compose.project"}}', check=False)
    removed = []
    for name in sorted(set(out.split())):
        m = PROJECT_RE.fullmatch(name)
        if m is None or _pid_alive(int(m.group(1))):
            continue
        topo.run([*topo.compose_cmd, "-p", name, "-f", str(COMPOSE), "down", "-v",
                  "--remove-orphans", "--timeout", "5"], check=False)
        removed.append(name)
    return removed


class ComposeTopology(BaseTopology):
    """The topology run by `docker compose` itself (see module docstring)."""

    mode = "compose"
    worker_link_unavailable = None

    def __init__(self, workdir: Path, overrides: dict[str, str] | None = None,
                 docker: str = "docker") -> None:
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.overrides = dict(overrides or {})
        self.docker_cmd = docker
        self.compose_cmd = compose_command(docker)
        self.project = f"cmrt-it-{os.getpid()}-{uuid.uuid4().hex[:8]}"
        self.api_port = free_port()
        self.override_file = self.workdir / "docker-compose.it.yml"
        self.extra: dict[str, dict[str, str]] = {name: {} for name in APP_SERVICES}
        self.procs: dict[str, list[Container]] = {}
        self.cut_links: list[str] = []
        self.warmed: set[str] = set()  # worker containers whose numba cache is compiled
        self._write_override()

    # -- docker ------------------------------------------------------------------------------
    def run(self, argv: list[str], check: bool = True, timeout: float = 900,
            stderr: bool = False) -> str:
        """Runs `argv` (a docker or compose command) with the overrides in its environment (so
        they reach the compose file's own ${VAR} interpolation); its stdout (and stderr)."""
        env = {**os.environ, **self.overrides, "CMRT_API_PORT": str(self.api_port)}
        env.pop("CMRT_API_BIND", None)  # the tests check the default: loopback only
        r = subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True,
                           timeout=timeout)
        if check and r.returncode != 0:
            raise RuntimeError(f"{' '.join(argv)} failed ({r.returncode}):\n"
                               f"{r.stdout}{r.stderr}")
        return r.stdout + (r.stderr if stderr else "")

    def docker(self, *args: str, check: bool = True, timeout: float = 900,
               stderr: bool = False) -> str:
        return self.run([self.docker_cmd, *args], check=check, timeout=timeout, stderr=stderr)

    def compose(self, *args: str, check: bool = True, timeout: float = 900) -> str:
        return self.run([*self.compose_cmd, "-p", self.project, "-f", str(COMPOSE),
                         "-f", str(self.override_file), *args], check=check, timeout=timeout)

    def _write_override(self) -> None:
        """The tests' settings on top of docker-compose.yml (compose merges `environment` and
        `healthcheck`)."""
        services = {name: {"healthcheck": dict(check)}
                    for name, check in TEST_HEALTHCHECKS.items()}
        for name in APP_SERVICES:
            services[name]["environment"] = {**self.overrides, **self.extra[name]}
        self.override_file.write_text(yaml.safe_dump({"services": services}, sort_keys=True))

    def _containers(self, name: str) -> list[Container]:
        """Every replica of `name`, running or not, keeping the objects already handed out."""
        known = {c.id: c for c in self.procs.get(name, [])}
        ids = self.compose("ps", "-a", "-q", name, check=False).split()
        out = [known.get(cid) or Container(self, f"{name}-{cid[:12]}", cid) for cid in ids]
        out += [c for cid, c in known.items() if cid not in ids]  # removed: keep for the record
        self.procs[name] = out
        return out

    def _wait_healthy(self, name: str, count: int = 1, timeout: float = 120) -> None:
        """Until `count` replicas of `name` are running and healthy by the compose file's check
        (what `docker compose up --wait` does; v1 has no --wait)."""
        def ok() -> bool:
            return sum(c.alive and c.health == "healthy" for c in self._containers(name)) >= count
        self._wait(ok, f"{count} healthy {name}", timeout)

    def up(self, name: str) -> None:
        """The service up (created or started) and healthy, without touching its dependencies."""
        self.compose("up", "-d", "--no-deps", "--no-build", name)
        self._wait_healthy(name)

    # -- infrastructure ----------------------------------------------------------------------
    def start_redis(self) -> None:
        sweep_stale_projects(self)
        self.up("redis")

    def stop_redis(self, wipe: bool = False) -> None:
        self.compose("kill", "-s", "KILL", "redis", check=False)
        if wipe:
            self.compose("rm", "-f", "-s", "redis", check=False)  # -s: even if restarted
            self.docker("volume", "rm", "-f", f"{self.project}_redisdata", check=False)

    def create_database(self) -> None:
        self.up("postgres")  # the image creates the database

    def drop_database(self) -> None:
        pass  # `down -v` in stop_all removes its volume

    def drop_database_connections(self) -> int:
        return int(self.sql("SELECT count(pg_terminate_backend(pid)) FROM pg_stat_activity "
                            "WHERE datname = 'cmrt' AND pid <> pg_backend_pid()")[-1])

    def sql(self, query: str) -> list[str]:
        """Rows of `query` on the application's database (psql in the postgres container,
        columns joined by |)."""
        out = self.compose("exec", "-T", "postgres", "psql", "-U", "cmrt", "-d", "cmrt", "-tAc",
                           query)
        return [ln for ln in out.splitlines() if ln.strip()]

    def inspect_json(self, container: Container, fmt: str):
        return json.loads(container.inspect(fmt))

    def warm_up(self) -> None:
        """The application image built as the compose file says (from the layer cache when
        scripts/docker-images.sh built it already)."""
        self.compose("build", "api")

    # -- application services ----------------------------------------------------------------
    def start(self, name: str, extra: dict[str, str] | None = None) -> Container:
        if extra and extra != self.extra[name]:
            self.extra[name] = dict(extra)
            self._write_override()
        running = [c for c in self._containers(name) if c.alive]
        if name == "api" and running:  # one API: it publishes the port (a restart policy may
            return running[0]  # have brought it back already)
        before = {c.id for c in running}
        self.scale(name, len(before) + 1)
        fresh = [c for c in self._containers(name) if c.alive and c.id not in before]
        if not fresh:
            raise RuntimeError(f"docker compose started no new {name} replica:\n{self.logs()}")
        if name == "api":
            self._wait_healthy("api")
            self._wait(self._api_ready, "api", 120, fresh[0])
        return fresh[0]

    def scale(self, name: str, count: int) -> None:
        """`count` running replicas of `name`: compose starts stopped ones before creating new
        ones. --no-deps: a worker must not bring the api up behind the tests' back. A worker
        container never warmed gets its numba cache compiled (WARM_UP) as local mode does."""
        self.compose("up", "-d", "--no-deps", "--no-recreate", "--no-build", "--scale",
                     f"{name}={count}", name)
        if name == "worker":
            for c in self._containers(name):
                if c.alive and c.id not in self.warmed:
                    self.docker("exec", c.id, "python", "-c", *WARM_UP, timeout=600)
                    self.warmed.add(c.id)

    def wait_workers_ready(self, count: int, timeout: float = 120) -> None:
        self._wait(lambda: sum(c.ready() for c in self._containers("worker")) >= count,
                   f"{count} workers", timeout)

    def url(self, path: str) -> str:
        return f"http://127.0.0.1:{self.api_port}{path}"

    def logs(self) -> str:
        return self.compose("logs", "--no-color", "--tail", "60", check=False)

    def stop_all(self) -> None:
        for link in self.cut_links:  # a drill stopped half way: no interface left down
            _ip("link", "set", link, "up", check=False)
        self.compose("down", "-v", "--remove-orphans", "--timeout", "10", check=False)

    # -- the workers' links ------------------------------------------------------------------
    def _host_links(self, container: Container) -> list[str]:
        """The machine's ends of the container's veth links (one per network it is on).

        Read by netlink inside the container's network namespace (`ip -o link` there shows
        `eth0@ifN`, N being the peer's index on this machine); /sys/class/net would show this
        machine's interfaces (sysfs is the mount's, not the namespace's), and the container's
        loopback has no peer: index 1 here is this machine's own `lo`, whose cut would take
        every local connection (the tests' HTTP calls to the API included) down with it."""
        wanted = set()
        for line in _ip("-o", "link", netns_pid=container.pid).splitlines():
            m = re.match(r"\d+: [^:@]+@if(\d+):", line)
            if m:
                wanted.add(int(m.group(1)))
        links = []
        for line in _ip("-o", "link").splitlines():
            index, name = line.split(":")[:2]
            if int(index) in wanted:
                links.append(name.strip().split("@")[0])
        if not links or "lo" in links:
            raise RuntimeError(f"no veth of {container.name} found on this machine: {links}")
        return links

    def cut_worker_link(self) -> None:
        """Every running worker container's link set down on the machine's side: its packets
        vanish without an answer, as in local mode (NetnsHost.cut)."""
        for c in self._containers("worker"):
            if c.alive:
                for link in self._host_links(c):
                    _ip("link", "set", link, "down")
                    self.cut_links.append(link)

    def restore_worker_link(self) -> None:
        while self.cut_links:
            _ip("link", "set", self.cut_links.pop(), "up")

    def workers_answering(self, timeout: float = 1.0) -> list[str]:
        """Node names of the Celery workers that answer a broadcast ping now, sent from the
        API's container (Redis is reachable on the compose network only)."""
        code = ("import json, sys; from celery import Celery; "
                "app = Celery('cmrt-it-ping', broker='redis://redis:6379/0'); "
                "print(json.dumps(app.control.ping(timeout=float(sys.argv[1]))))")
        out = self.compose("exec", "-T", "api", "python", "-c", code, str(timeout),
                           timeout=60 + timeout)
        return sorted(name for reply in json.loads(out.strip().splitlines()[-1])
                      for name in reply)


def make_topology(workdir: Path, overrides: dict[str, str] | None = None) -> BaseTopology:
    """The topology CMRT_IT_MODE names: local (the default, whether or not an engine runs here:
    `make test` must not change with the machine) or compose (`make test-compose`)."""
    mode = os.environ.get("CMRT_IT_MODE") or "local"
    if mode == "compose":
        return ComposeTopology(workdir, overrides)
    if mode == "local":
        return LocalTopology(workdir, overrides=dict(overrides or {}))
    raise ValueError(f"CMRT_IT_MODE must be compose or local, got {mode!r}")


def _set_opt(argv: list[str], opt: str, value: str) -> list[str]:
    if opt in argv:
        i = argv.index(opt)
        return argv[: i + 1] + [value] + argv[i + 2:]
    return argv + [opt, value]


def _redis_ping(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1) as s:
            s.sendall(b"PING\r\n")
            return s.recv(16).startswith(b"+PONG")
    except OSError:
        return False
