"""`cmrt.client` and the client commands (submit, jobs, watch, library) against a real
`cmrt serve` (embedded default: SQLite file, local process pool of 1, real simulations of short
bends), started as a process on a free port."""

from __future__ import annotations

import json
import os
import pty
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
import yaml
from proc_helpers import free_port, tiny_bend

from cmrt.client import (
    Client,
    InvalidRequestError,
    NotFoundError,
    Progress,
    ServiceUnreachableError,
    UnauthorizedError,
    WaitTimeoutError,
    split_detail,
)

ROOT = Path(__file__).resolve().parents[2]
CMRT = ROOT / ".venv" / "bin" / "cmrt"
#: 3 generations of 4 candidates of a 0.8 s clip: about a second of CPU in all.
TINY = {"popsize": 4, "max_evaluations": 12, "min_evaluations": 0}


def bend(name: str, duration: float = 0.3) -> dict:
    return tiny_bend(name, duration, TINY)


def _free_port() -> int:
    return free_port()


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update(extra)
    return env


def _serve(tmp: Path, **extra: str) -> tuple[subprocess.Popen, str]:
    port = _free_port()
    # a family steps at each scan: every 0.2 s instead of 2 s, so families end in seconds
    env = _env(**{"CMRT_DATA_DIR": str(tmp / "data"), "CMRT_WORKERS": "1",
                  "CMRT_API_PORT": str(port), "CMRT_LOG_LEVEL": "WARNING",
                  "CMRT_SCAN_INTERVAL": "0.2", **extra})
    proc = subprocess.Popen([str(CMRT), "serve"], env=env, cwd=tmp,
                            stdout=(tmp / "serve.log").open("wb"), stderr=subprocess.STDOUT,
                            start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    t0 = time.monotonic()
    while True:
        assert proc.poll() is None, (tmp / "serve.log").read_text()[-3000:]
        try:
            if httpx.get(f"{url}/health", timeout=2).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            pass
        assert time.monotonic() - t0 < 90, "cmrt serve did not become healthy"
        time.sleep(0.2)


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    """A running `cmrt serve`, its client, and two finished bends (T = 0.3 s and 0.5 s) in
    its library."""
    tmp = tmp_path_factory.mktemp("client")
    proc, url = _serve(tmp)
    client = Client(url)
    try:
        done = {}
        for t in (0.3, 0.5):
            job = client.submit(bend(f"lib_{t}", t), seed=1)
            done[t] = job.wait(timeout=120)
        yield client, url, tmp, done
    finally:
        client.close()
        _stop(proc)


def _cli(url: str | None, *argv: str, timeout: float = 120, **env: str):
    extra = {"CMRT_URL": url} if url else {}
    return subprocess.run([str(CMRT), *argv], env=_env(**extra, **env), capture_output=True,
                          text=True, timeout=timeout)


# ---- the Python client --------------------------------------------------------------------
def test_submit_wait_generations_best(service):
    client, _url, _tmp, _done = service
    job = client.submit(bend("client_a"), seed=3)
    assert job.budget["evaluations"] == 12 + 4 - 1 + 2  # the cap, a last generation, the pair
    seen: list[Progress] = []
    final = job.wait(timeout=120, on_progress=seen.append)
    assert final["status"] == "stopped" and final["stop_rule"] == "max_evaluations"
    assert final["evaluations"] == 12 and job.status() == "stopped"
    # wait() fetched every generation exactly once (?after=), in order
    polled = [g["iteration"] for p in seen for g in p.new]
    assert polled == [0, 1, 2]
    assert seen[-1].done and seen[-1].max_evaluations == 12 and seen[-1].generation == 2
    gens = job.generations()
    assert [g["iteration"] for g in gens] == [0, 1, 2]
    assert [g["iteration"] for g in job.generations(after=0)] == [1, 2]
    assert [g["evaluations"] for g in gens] == [4, 8, 12]
    assert min(g["best"] for g in gens) == gens[-1]["best_so_far"] == final["best_objective"]
    best = job.best()
    assert best["objective"] == final["best_objective"] and len(best["params"]) == 8
    entry = best["cmrt"]
    assert entry["id"] == final["cmrt_id"] and entry["winner"] in ("search", "flat")
    # the library keeps the better of the best candidate and the flat spline
    assert entry["objective"] == min(final["best_objective"], entry["objective_without"])
    # the same seed gives the same search (real physics, deterministic)
    again = client.submit(bend("client_a_again"), seed=3).wait(timeout=120)
    assert again["best_objective"] == final["best_objective"]
    assert again["best_params"] == final["best_params"]


def test_a_jobs_motion_files(service, tmp_path):
    """Job.motion: the best candidate's clip as the service writes it (BVH, CSV at a rate),
    kept in a file when asked; a bad rate is the server's 422 naming the field."""
    client, _url, _tmp, done = service
    job = client.job(done[0.3]["id"])
    bvh = job.motion(out=tmp_path / "m.bvh")
    # a 0.8 s clip: frames at 0 .. 0.783 s (60 fps), 0 .. 0.7 s (10 fps)
    assert bvh.startswith("HIERARCHY\nROOT pelvis\n") and "\nFrames: 48\n" in bvh
    assert (tmp_path / "m.bvh").read_text() == bvh
    table = job.motion("csv", fps=10)
    assert table.startswith("t,root_x,root_y,root_angle,") and table.count("\n") == 1 + 8
    with pytest.raises(InvalidRequestError, match="fps: "):
        job.motion("csv", fps=5000)


def test_jobs_filters(service):
    client, _url, _tmp, done = service
    ids = {j.id for j in client.jobs(family="bend", limit=200)}
    assert {d["id"] for d in done.values()} <= ids
    assert client.jobs(family="no_such_family") == []
    assert all(j.data["status"] == "stopped" for j in client.jobs(status="stopped"))
    assert not {j.id for j in client.jobs(status="running")} & {d["id"] for d in done.values()}


def test_library_query_interpolate_and_simulate(service):
    client, _url, _tmp, done = service
    at_03 = client.cmrts(family="bend", duration=0.3)
    assert done[0.3]["cmrt_id"] in {e["id"] for e in at_03}
    assert all(e["task_parameters"]["duration"] == 0.3 for e in at_03)
    near = client.cmrts(family="bend", duration=0.45, tolerance=0.1)
    assert near[0]["task_parameters"]["duration"] == 0.5  # nearest first
    out = client.interpolate(family="bend", duration=0.4)
    assert sorted(n["task_parameters"]["duration"] for n in out["neighbours"]) == [0.3, 0.5]
    with pytest.raises(InvalidRequestError) as err:
        client.interpolate(family="bend", duration=0.9)  # outside 0.3..0.5
    assert err.value.status == 422
    # a what-if clip with the library CMRT replays its stored objective (the same simulation)
    entry = client.cmrt(done[0.3]["cmrt_id"])
    spec = entry["source"]["spec"]
    sim = client.simulate(spec, cmrt=entry["id"])
    assert sim["status"] == "done" and sim["objective"] == entry["objective"]
    flat = client.simulate(spec)
    assert flat["objective"] == entry["objective_without"] and flat["cmrt"] is None


def test_server_errors_are_typed_and_name_the_field(service):
    client, _url, _tmp, _done = service
    before = len(client.jobs(limit=200))
    bad = bend("bad")
    bad["clip"]["preparation"] = -1.0
    with pytest.raises(InvalidRequestError) as err:
        client.submit(bad)
    e = err.value
    assert e.status == 422 and e.field == "spec.clip.preparation"
    assert "must be from 0 to 10 s, got -1.0" in e.rule and "preparation" in str(e)
    assert len(client.jobs(limit=200)) == before  # nothing stored on a 4xx
    with pytest.raises(InvalidRequestError, match="unknown task type 'juggle'"):
        client.submit({**bend("juggler"), "task": {"type": "juggle"}})
    with pytest.raises(NotFoundError):
        client.job("no-such-job")
    with pytest.raises(InvalidRequestError) as err:
        client.cmrts(duration=0.3)  # task parameters need a family
    assert err.value.field == "family"


def test_wait_timeout_and_unreachable(service, tmp_path):
    client, _url, _tmp, _done = service
    job = client.submit({**bend("slowish"), "optimize": {**TINY, "max_evaluations": 400}})
    with pytest.raises(WaitTimeoutError):
        job.wait(timeout=0.2)
    job.cancel()
    assert job.wait(timeout=60)["status"] == "cancelled"
    dead = Client(f"http://127.0.0.1:{_free_port()}")
    with pytest.raises(ServiceUnreachableError, match="cannot reach the CMRT service"):
        dead.jobs()


def test_split_detail():
    assert split_detail("spec: clip.preparation: must be >= 0") == (
        "spec.clip.preparation", "must be >= 0")
    assert split_detail("cmrt.params: expected 8 numbers: got 3") == (
        "cmrt.params", "expected 8 numbers: got 3")
    assert split_detail("job abc already finished (stopped)") == (
        None, "job abc already finished (stopped)")


# ---- the command line ---------------------------------------------------------------------
def test_cli_submit_wait_jobs_watch_library(service, tmp_path):
    _client, url, _tmp, done = service
    spec = tmp_path / "bend.yaml"
    spec.write_text(yaml.safe_dump(bend("cli_bend")))
    p = _cli(url, "submit", str(spec), "--seed", "3", "--wait")
    assert p.returncode == 0, p.stderr
    lines = p.stdout.splitlines()
    job_id = re.match(r"job (\S+) submitted: ", lines[0]).group(1)
    gen_lines = [ln for ln in lines if ln.startswith("gen ")]  # not a terminal: plain lines
    assert [int(ln.split()[1]) for ln in gen_lines] == [0, 1, 2]
    assert re.fullmatch(r"gen +2  evals +12  best +\d+\.\d{4}  sigma +\d\.\d{4} +\d+\.\d s",
                        gen_lines[-1])
    assert any(ln.startswith(f"job {job_id} stopped (max_evaluations): 12 evaluations")
               for ln in lines)
    assert any(ln.startswith("library CMRT ") for ln in lines)
    # watch a finished job: the same generations, then the result
    w = _cli(url, "watch", job_id)
    assert w.returncode == 0, w.stderr
    assert [ln for ln in w.stdout.splitlines() if ln.startswith("gen ")] == gen_lines
    j = _cli(url, "jobs", "--family", "bend", "--status", "stopped")
    assert j.returncode == 0 and job_id in j.stdout and done[0.3]["id"] in j.stdout
    js = json.loads(_cli(url, "jobs", "--json").stdout)
    assert job_id in {d["id"] for d in js}
    lib = _cli(url, "library", "list", "--family", "bend", "duration=0.5")
    assert lib.returncode == 0 and done[0.5]["cmrt_id"] in lib.stdout
    assert done[0.3]["cmrt_id"] not in lib.stdout
    show = _cli(url, "library", "show", done[0.5]["cmrt_id"], "--json")
    assert json.loads(show.stdout)["task_parameters"] == {"duration": 0.5}
    it = _cli(url, "library", "interpolate", "--family", "bend", "duration=0.4", "--json")
    assert it.returncode == 0, it.stderr
    assert len(json.loads(it.stdout)["curve"]) > 0


def test_cli_bad_input_exits_2_naming_the_field(service, tmp_path):
    _client, url, _tmp, _done = service
    bad = bend("bad")
    bad["clip"]["preparation"] = -1.0
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(bad))
    p = _cli(url, "submit", str(path))
    assert p.returncode == 2 and "spec: clip.preparation:" in p.stderr
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1
    for argv, said in ((["submit", str(tmp_path / "none.yaml")], "no such file"),
                       (["watch", "no-such-job"], "no-such-job"),
                       (["library", "list", "--family", "bend", "duration"], "NAME=VALUE"),
                       (["library", "list", "--family", "bend", "duration=x"], "not a number"),
                       (["submit", str(path), "--seed", "-1"], "[0, 2^31)"),
                       (["jobs", "--limit", "0"], "limit")):
        q = _cli(url, *argv)
        assert q.returncode == 2, (argv, q.stdout, q.stderr)
        assert said in q.stderr and "Traceback" not in q.stderr, (argv, q.stderr)


def test_cli_unreachable_service_is_one_clear_line(tmp_path):
    url = f"http://127.0.0.1:{_free_port()}"
    for argv in (["jobs"], ["watch", "x"], ["library", "list"]):
        p = _cli(None, *argv, "--url", url)
        assert p.returncode == 3, p.stderr
        assert p.stderr.startswith(f"cmrt: error: cannot reach the CMRT service at {url}")
        assert "Traceback" not in p.stderr
    # the URL comes from the settings (CMRT_URL) when --url is not given
    p = _cli(url, "jobs")
    assert p.returncode == 3 and url in p.stderr
    p = _cli(None, "jobs", CMRT_URL="not a url")
    assert p.returncode == 2 and "CMRT_URL" in p.stderr and "Traceback" not in p.stderr


def test_client_commands_load_no_simulator(tmp_path):
    """docs/architecture.md: `cmrt --help`, `cmrt submit` or `cmrt jobs` never load the
    simulator, numba, SQLAlchemy or Celery (a client command starts in a fraction of a second),
    a failing one included; a spec error of a command that simulates is still one line,
    exit 2."""
    url = f"http://127.0.0.1:{_free_port()}"
    code = (
        "import contextlib, sys\n"
        "from cli.main import main\n"
        "with contextlib.suppress(SystemExit):\n"
        "    main(['--help'])\n"
        f"codes = [main(['jobs', '--url', {url!r}]), main(['watch', 'x', '--url', {url!r}])]\n"
        "bad = sorted({m.split('.')[0] for m in sys.modules} & {'sim', 'numba', 'sqlalchemy',"
        " 'celery'})\n"
        "print(codes, bad)\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                       timeout=120, cwd=tmp_path, env=_env(PYTHONPATH=str(ROOT)))
    assert p.stdout.strip().splitlines()[-1] == "[3, 3] []", p.stdout + p.stderr
    bad = tmp_path / "bad.yaml"  # a command that loads the simulator: its errors are caught
    bad.write_text(yaml.safe_dump({**bend("bad"), "clip": {"duration": -1}}))
    p = _cli(None, "simulate", str(bad))
    assert p.returncode == 2 and p.stderr.startswith("cmrt: error: ") and \
        "clip" in p.stderr and "Traceback" not in p.stderr, p.stderr


def _run_in_pty(argv: list[str], env: dict[str, str], timeout: float = 120) -> tuple[int, str]:
    """Run a command with stdout and stderr on a pseudo-terminal; its exit status and output."""
    master, slave = pty.openpty()
    proc = subprocess.Popen(argv, env={**env, "COLUMNS": "100", "TERM": "xterm"},
                            stdin=subprocess.DEVNULL, stdout=slave, stderr=slave)
    os.close(slave)
    out = b""
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            r, _, _ = select.select([master], [], [], 0.5)
            if r:
                try:
                    chunk = os.read(master, 65536)
                except OSError:  # the child closed the terminal
                    break
                if not chunk:
                    break
                out += chunk
            elif proc.poll() is not None:
                break
        return proc.wait(timeout=30), out.decode(errors="replace")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)


def test_watch_on_a_terminal_draws_a_rich_bar(service):
    client, url, _tmp, done = service
    code, out = _run_in_pty([str(CMRT), "watch", done[0.3]["id"]], _env(CMRT_URL=url))
    assert code == 0, out
    assert "━" in out and "12/12" in out and "evals" in out  # rich's bar and its columns
    assert "gen   2" in out and "stopped" in out
    assert not re.search(r"^gen +0  evals", out, re.M)  # no plain lines on a terminal


def test_optimize_bar_on_a_terminal_plain_lines_otherwise(tmp_path):
    spec = tmp_path / "bend.yaml"
    spec.write_text(yaml.safe_dump({**bend("opt_bend"),
                                    "optimize": {**TINY, "max_evaluations": 8}}))
    argv = [str(CMRT), "optimize", str(spec), "--workers", "1", "--seed", "2"]
    code, out = _run_in_pty([*argv, "--out", str(tmp_path / "tty.json")], _env())
    assert code == 0, out
    assert "━" in out and "8/8" in out and "objective:" in out
    p = subprocess.run([*argv, "--out", str(tmp_path / "plain.json")], env=_env(),
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if ln.startswith("gen")]
    assert [ln.split()[:4] for ln in lines] == [["gen", "0", "evals", "4"],
                                               ["gen", "1", "evals", "8"]]
    assert "━" not in p.stderr and "\r" not in p.stderr
    assert json.loads((tmp_path / "tty.json").read_text())["objective"] == json.loads(
        (tmp_path / "plain.json").read_text())["objective"]


def test_token_from_the_settings(tmp_path):
    proc, url = _serve(tmp_path, CMRT_API_TOKEN="s3cret")
    try:
        with pytest.raises(UnauthorizedError) as err:
            Client(url).jobs()
        assert err.value.status == 401
        assert Client(url, token="s3cret").jobs() == []
        p = _cli(url, "jobs")
        assert p.returncode == 2 and "token" in p.stderr.lower()
        p = _cli(url, "jobs", CMRT_API_TOKEN="s3cret")
        assert p.returncode == 0, p.stderr
    finally:
        _stop(proc)


#: A cheap real family: the quiet stance along its decay (5 values, continuation from both).
CALM = {"name": "calm", "family": "calm", "task": {"type": "quiet_stance"},
        "clip": {"preparation": 0.3, "duration": 0.2, "decay": 0.4},
        "optimize": {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0, "window": 2}}


def test_family_submit_show_watch_and_the_python_client(service, tmp_path):
    _, service, _, _ = service
    spec = tmp_path / "calm.yaml"
    spec.write_text(yaml.safe_dump(CALM))
    base = ["family", "submit", str(spec), "--param", "clip.decay",
            "--values", "0.4", "0.5", "0.6", "0.7", "--strategy", "continuation",
            "--leave-out", "0.5", "--k", "2", "--warm", "max_evaluations=4", "window=2"]
    r = _cli(service, *base, "--json")
    assert r.returncode == 0, r.stderr
    fid = json.loads(r.stdout)["id"]
    r = _cli(service, "family", "watch", fid, timeout=300)
    assert r.returncode == 0, r.stderr + r.stdout
    assert f"family {fid} done" in r.stdout and "| decay |" in r.stdout
    shown = json.loads(_cli(service, "family", "show", fid, "--json").stdout)
    assert [m["value"] for m in shown["members"]] == [0.4, 0.5, 0.6, 0.7]
    assert [row["value"] for row in shown["checks"]["rows"]] == [0.5]
    with Client(service) as c:
        fam = c.family(fid)
        assert fam.status() == "done" and fam.id in [f.id for f in c.families()]
        assert all(len(run["curve"]) >= 1 for run in fam.refresh(curves=True)["runs"])
    # bad input: exit 2 naming the field, nothing stored
    before = len(Client(service).families())
    i = base.index("--leave-out")
    bad = _cli(service, *base[:i + 1], "0.55", *base[i + 2:])
    assert bad.returncode == 2 and "leave_out[0]" in bad.stderr, bad.stderr
    assert _cli(service, "family", "show", "nope").returncode == 2
    assert len(Client(service).families()) == before


def test_a_read_on_a_connection_the_server_closed_is_sent_again():
    """A kept-alive connection closed by the server as a GET goes out (its idle timeout) is
    retried once on a new connection; a POST is not (it may have been received)."""
    import threading
    from http.server import BaseHTTPRequestHandler, HTTPServer

    seen: list[str] = []

    class Handler(BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802
            seen.append(self.path)
            if len(seen) == 1:  # the first request: close without an answer
                self.close_connection = True
                return
            body = b'{"status": "ok"}'
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        do_POST = do_GET  # noqa: N815

        def log_message(self, *args):
            pass

    srv = HTTPServer(("127.0.0.1", 0), Handler)
    t = threading.Thread(target=srv.serve_forever, daemon=True)
    t.start()
    try:
        with Client(f"http://127.0.0.1:{srv.server_port}") as c:
            assert c.health() == {"status": "ok"} and seen == ["/health", "/health"]
            seen.clear()
            with pytest.raises(ServiceUnreachableError):
                c._request("POST", "/jobs", json_body={})
            assert seen == ["/jobs"]
    finally:
        srv.shutdown()


def test_characters_add_list_show_and_a_job_naming_one(service, tmp_path):
    """`cmrt characters add/list/show` on a real service, then a spec naming the stored
    character: the job holds its definition; a bad file exits 2 naming the field."""
    client, url, _tmp, _done = service
    mine = ROOT / "examples" / "my_character.yaml"
    p = _cli(url, "characters", "add", str(mine), "--name", "client_mine")
    assert p.returncode == 0, p.stderr
    assert "character client_mine stored" in p.stdout
    again = _cli(url, "characters", "add", str(mine), "--name", "client_mine")
    assert again.returncode == 2 and "name: a character named 'client_mine' exists" in \
        again.stderr
    listed = _cli(url, "characters", "list")
    assert listed.returncode == 0 and re.search(r"^client_mine +stored +1\.793 +74\.97 +13 ",
                                                listed.stdout, re.M), listed.stdout
    shown = json.loads(_cli(url, "characters", "show", "client_mine", "--json").stdout)
    assert shown["definition"] == yaml.safe_load(mine.read_text())
    bad = yaml.safe_load(mine.read_text())
    bad["segments"][2]["mass"] = 1e-9
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
    q = _cli(url, "characters", "add", str(tmp_path / "bad.yaml"), "--name", "bad_one")
    assert q.returncode == 2 and "definition: segments[2].mass: must be at least 0.1 kg" in \
        q.stderr and "Traceback" not in q.stderr
    assert client.characters()["total"] == 1
    job = client.submit({**bend("stored_char"), "character": {"model": "client_mine"}})
    assert client.job(job.id).data["spec"]["character"]["definition"] == shown["definition"]
