"""Every command the README and its command pages show, run as written (the project rule),
in a scratch folder.

The pages are README.md, docs/cli.md (every `cmrt` command) and docs/api.md (the HTTP API by
curl); a line shown on two of them (the README repeats a few) runs once.
`test_every_readme_command_is_covered` reads their ```sh blocks and fails on a command
no test here runs, so a command added to the README without a test fails the suite. How each
one runs (and the few substitutions, each said where it is made):
  * long runs get tiny budgets, not other arguments: the scratch folder's
    `examples/fast_bend.yaml` is the real one with `optimize` cut to one generation, so
    `make run`'s and the README's `cmrt optimize examples/fast_bend.yaml ...` lines run
    verbatim; bench/ scripts (30-80 min) run with `--help`;
  * optional parts `[...]` run in every form shown (each option once);
  * `make run` / `make test` are checked with `make -n` (dry run; `make test` is what runs
    this file, and the optimise command of `make run` runs verbatim below);
  * the servers run on a free port (`CMRT_API_PORT` / `--port`: 8000 may be taken on a shared
    machine) against the test PostgreSQL and Redis instead of the README's example URLs;
    the embedded server of the client commands steps its family every 0.2 s
    (`CMRT_SCAN_INTERVAL`, 2 s by default);
  * `docker compose` lines run in the compose suite only (`make test-compose`, which sets
    CMRT_IT_MODE=compose and needs an engine); elsewhere they are skipped with that reason;
  * `open URL` (macOS) runs as `curl -s URL`;
  * `$JOB` is the first job submitted, except in the cancel line, which cancels the second
    (the slow bend's) so that the first runs to its end: its result is checked against what
    the README says of it (converged, standing, better than the flat spline).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
#: The pages whose ```sh blocks run here, in reading order.
COMMAND_PAGES = (README, ROOT / "docs" / "cli.md", ROOT / "docs" / "api.md")
VENV_BIN = ROOT / ".venv" / "bin"
PG_URL = os.environ.get(
    "CMRT_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test"
)
REDIS = os.environ.get("CMRT_TEST_REDIS", "redis://127.0.0.1:6379")
#: One generation of the smallest population: what "a tiny budget" means here.
TINY = {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0}


def readme_commands() -> list[str]:
    """The commands of the command pages' ```sh blocks: continuation lines and open quotes
    joined, comment-only and output lines (`# ...`) left out, a line shown twice kept once."""
    out = []
    text = "\n".join(page.read_text() for page in COMMAND_PAGES)
    for block in re.findall(r"```sh\n(.*?)```", text, re.S):
        cur = ""
        for line in block.splitlines():
            cur = f"{cur}\n{line}" if cur else line
            if cur.endswith("\\"):
                continue
            try:
                shlex.split(cur, comments=True)
            except ValueError:  # an open quote: the command goes on
                continue
            if cur.strip() and not cur.lstrip().startswith("#") and cur.strip() not in out:
                out.append(cur.strip())
            cur = ""
    return out


def _strip_comment(cmd: str) -> str:
    return re.sub(r"\s+#.*$", "", cmd.split("\n")[0]) if "\n" not in cmd else cmd


def _expand_optional(cmd: str) -> list[str]:
    """`a [--x | --y V] [--z]` -> ["a", "a --x", "a --y V", "a --z"] (each option once)."""
    base = re.sub(r"\s*\[.*$", "", cmd)
    forms = [base]
    for group in re.findall(r"\[([^\[\]]*(?:\[[^\]]*\][^\[\]]*)*)\]", cmd):
        for alt in group.split(" | "):
            option = re.sub(r"[\[\]]", "", alt).strip()
            forms.append(f"{base} {option}")
    return forms


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def scratch(tmp_path_factory):
    """A folder laid out like the repository root: .venv and bench/ link to the real ones,
    examples/ are copies (fast_bend with a tiny budget), results/ holds four bend results."""
    d = tmp_path_factory.mktemp("readme")
    (d / ".venv").symlink_to(ROOT / ".venv")
    (d / "bench").symlink_to(ROOT / "bench")
    shutil.copytree(ROOT / "examples", d / "examples")
    shutil.copy(ROOT / "Makefile", d / "Makefile")
    shutil.copytree(ROOT / "scripts", d / "scripts")
    fast = yaml.safe_load((d / "examples" / "fast_bend.yaml").read_text())
    fast["optimize"] = {**fast.get("optimize", {}), **TINY}
    (d / "examples" / "fast_bend.yaml").write_text(yaml.safe_dump(fast))
    from cli.main import main

    for dur in (0.3, 0.5, 0.7, 0.9):
        spec = {**fast, "name": f"bend_{dur}", "clip": {"preparation": 0.3, "duration": dur,
                                                       "decay": 0.3}}
        path = d / f"bend_{dur}.yaml"
        path.write_text(yaml.safe_dump(spec))
        assert main(["optimize", str(path), "--workers", "1", "--seed", "1",
                     "--out", str(d / "results" / f"bend_{dur}.json")]) == 0
    return d


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env["PATH"] = f"{VENV_BIN}{os.pathsep}{env.get('PATH', '')}"
    env.update(extra)
    return env


def _run(cmd: str, cwd: Path, env: dict[str, str] | None = None, timeout: float = 300.0):
    p = subprocess.run(["bash", "-c", cmd], cwd=cwd, env=env or _env(), capture_output=True,
                       text=True, timeout=timeout)
    assert p.returncode == 0, f"{cmd!r} exited {p.returncode}:\n{p.stdout[-2000:]}\n" \
                              f"{p.stderr[-3000:]}"
    return p


# ---- which test runs which README command -----------------------------------------------
COVERED = {
    "make run": "test_make_targets_resolve",
    "make test": "test_make_targets_resolve",
    ".venv/bin/cmrt simulate": "test_cli_block",
    ".venv/bin/cmrt optimize": "test_cli_block",
    ".venv/bin/cmrt pca": "test_cli_block",
    ".venv/bin/cmrt interpolate": "test_cli_block",
    ".venv/bin/cmrt bench": "test_cli_block",
    ".venv/bin/cmrt sweep": "test_cli_block",
    ".venv/bin/cmrt robustness": "test_cli_block",
    ".venv/bin/cmrt family run": "test_family_command",
    ".venv/bin/cmrt family submit": "test_client_commands",
    ".venv/bin/cmrt driver": "tests/cli/test_driver_process.py",
    ".venv/bin/cmrt family show": "test_client_commands",
    ".venv/bin/cmrt family watch": "test_client_commands",
    ".venv/bin/cmrt serve": "test_cmrt_serve_embedded",
    ".venv/bin/cmrt worker": "test_cmrt_worker",
    ".venv/bin/python bench/": "test_bench_scripts_help",
    "cp .env.example .env": "test_docker_block",
    "docker compose": "test_docker_block",
    "export CMRT_": "test_servers_and_every_curl",
    "cmrt serve --host": "test_servers_and_every_curl",
    "cmrt worker --concurrency": "test_servers_and_every_curl",
    "curl ": "test_servers_and_every_curl",
    "python -c ": "test_servers_and_every_curl",
    "open $API": "test_servers_and_every_curl",
    ".venv/bin/cmrt submit": "test_client_commands",
    ".venv/bin/cmrt jobs": "test_client_commands",
    ".venv/bin/cmrt watch": "test_client_commands",
    ".venv/bin/cmrt library": "test_client_commands",
    ".venv/bin/cmrt characters": "test_client_commands",
    ".venv/bin/cmrt motion import": "test_motion_import_commands",
}


def test_every_readme_command_is_covered():
    cmds = readme_commands()
    assert len(cmds) > 40, "the README parser lost its commands"
    missing = [c for c in cmds if not any(c.startswith(p) for p in COVERED)]
    assert not missing, f"README commands no test runs: {missing}"


def test_make_targets_resolve(scratch):
    for line in readme_commands():
        if line.startswith("make "):
            target = _strip_comment(line).split()[1]
            p = _run(f"make -n {target}", scratch)
            if target == "test-compose":  # the compose suite (needs an engine): its steps
                assert "docker-images.sh" in p.stdout and "CMRT_IT_MODE=compose" in p.stdout
            else:
                assert target == "test" or "cmrt optimize" in p.stdout


def _family_command() -> str:
    """The README's `cmrt family run` line (its comment cut off)."""
    return next(_strip_comment(c) for c in readme_commands()
                if c.startswith(".venv/bin/cmrt family run"))


def _run_family_form(form: str, d: Path) -> tuple[subprocess.CompletedProcess, dict]:
    """`form` of the family command run in `d`, afresh unless it is the --resume form (its
    output's run folder removed first); the process and the output document it wrote."""
    out = d / re.search(r"--out (\S+)", form).group(1)
    if "--resume" not in form:
        shutil.rmtree(out.with_suffix(".runs"), ignore_errors=True)
    p = _run(form, d)
    return p, json.loads(out.read_text())


@pytest.fixture(scope="module")
def first_family_form(scratch) -> tuple[str, subprocess.CompletedProcess, dict]:
    """The family command's first form (no options), run afresh once for the module: its
    members feed the `pca` and `interpolate` lines and `test_family_command` checks its output
    (the family takes the longest of the CLI lines, so it runs once, not once per test)."""
    form = _expand_optional(_family_command())[0]
    return (form, *_run_family_form(form, scratch))


def _family_members(d: Path, pattern: str) -> None:
    """The result files `pattern` names (the README's `pca` and `interpolate` lines read the
    members `cmrt family run` saved), made again by the family command's first form if a
    later form replaced them."""
    if not list(d.glob(pattern)):
        _run_family_form(_expand_optional(_family_command())[0], d)
    assert len(list(d.glob(pattern))) >= 3, sorted(p.name for p in d.rglob("*.json"))


def test_cli_block(scratch, first_family_form):
    d = scratch
    shutil.copy(d / "results" / "bend_0.5.json", d / "RESULT.json")
    lines = [_strip_comment(c) for c in readme_commands() if c.startswith(".venv/bin/cmrt ")]
    # outputs feed later ones
    order = ("optimize", "pca", "interpolate", "simulate", "bench", "sweep", "robustness")
    lines = sorted((c for c in lines if c.split()[1] in order),
                   key=lambda c: order.index(c.split()[1]))
    ran = []
    pca = next(c for c in lines if c.split()[1] == "pca")
    for line in lines:
        if line.split()[1] in ("pca", "interpolate"):  # the family run's members, as shown
            _family_members(d, line.split()[2])
        for form in _expand_optional(line):
            if "--basis BASIS.json" in form and not (d / "BASIS.json").exists():
                _family_members(d, pca.split()[2])
                _run(pca.replace("--out bend_basis.json", "--out BASIS.json"), d)
            if "--warm-start R.json" in form:
                shutil.copy(d / "results" / "fast_bend.json", d / "R.json")
            p = _run(form, d)
            ran.append(form)
            if " --json" in form:
                json.loads(p.stdout.strip().splitlines()[-1])
            elif form.split()[1] == "sweep":  # the table: a row per force, the survived runs
                assert "forward 0.4 s: survived" in p.stdout, p.stdout
            elif form.split()[1] == "robustness":  # a row per value, then where each holds
                assert "flat spline holds at clip.duration" in p.stdout, p.stdout
    assert (d / "results" / "fast_bend.json").exists() and (d / "bend_basis.json").exists()
    assert (d / "curve.json").exists() and (d / "OUT.csv").read_text().startswith("t,")
    assert (d / "fast_bend.bvh").read_text().startswith("HIERARCHY\nROOT pelvis\n")
    assert (d / "fast_bend.csv").read_text().startswith("t,root_x,root_y,root_angle,waist,")
    assert any("--resume" in f for f in ran) and any("--extrapolate" in f for f in ran)
    for replay in ("flat.html", "fast_bend.html"):  # self-contained replay files, < 1 MB
        html = (d / replay).read_text()
        assert 'id="replay-data"' in html and len(html.encode()) < 1_000_000


def test_motion_import_commands(scratch):
    """Every `cmrt motion import` line in each form, with the repository's tests/data (the
    clips) beside the scratch folder's examples; the README's line makes the shipped example."""
    d = scratch
    if not (d / "tests").exists():
        (d / "tests").symlink_to(ROOT / "tests")
    lines = [_strip_comment(c) for c in readme_commands()
             if c.startswith(".venv/bin/cmrt motion import")]
    assert len(lines) >= 2
    for line in lines:
        for form in _expand_optional(line):
            p = _run(form, d)
            assert "wrote " in p.stdout and "clipped: " in p.stdout, p.stdout
    made = d / "motion_bend.yaml"
    assert made.read_bytes() == (ROOT / "examples" / "motion_bend.yaml").read_bytes()


def test_family_command(scratch, first_family_form):
    """`cmrt family run` in every form shown, on the scratch fast bend's tiny budget; a form
    without --resume starts afresh (its output's run folder removed first). The first form
    ran once for the module (`first_family_form`); the others run here, after it."""
    first, p, doc = first_family_form
    lines = [_strip_comment(c) for c in readme_commands()
             if c.startswith(".venv/bin/cmrt family run")]
    assert lines
    for line in lines:
        for form in _expand_optional(line):
            if form != first:
                p, doc = _run_family_form(form, scratch)
            assert doc["checks"]["rows"] and "median speed-up" in p.stdout


def test_bench_scripts_help(scratch):
    """Every bench/ script the README shows answers --help (all started at once: each is a
    Python start-up and its imports, and they are independent)."""
    procs = {}
    for line in readme_commands():
        if line.startswith(".venv/bin/python bench/"):
            cmd = f".venv/bin/python {line.split()[1]} --help"
            procs[cmd] = subprocess.Popen(["bash", "-c", cmd], cwd=scratch, env=_env(),
                                          stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                          text=True)
    try:
        assert len(procs) > 10, procs
        for cmd, proc in procs.items():
            out, err = proc.communicate(timeout=120)
            assert proc.returncode == 0, f"{cmd!r} exited {proc.returncode}:\n{err[-3000:]}"
            assert "usage" in out.lower(), out
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)


def test_docker_block(tmp_path):
    """The README's Docker Compose block. The cp line runs in a scratch folder; the `docker
    compose` lines run in the checkout (the build context) in compose mode only, as a private
    project (COMPOSE_PROJECT_NAME) with the API on a free port (CMRT_API_PORT: 8000 may be
    taken), with `docker-compose` (v1, same arguments) where the v2 plugin is absent, and
    `logs -f` stopped after a few seconds; then the API answers, 4 workers run, and
    `down -v` removes the project."""
    shutil.copy(ROOT / ".env.example", tmp_path / ".env.example")
    lines = [c for c in readme_commands() if c.startswith(("cp ", "docker "))]
    _run(_strip_comment(lines[0]), tmp_path)
    assert (tmp_path / ".env").read_text() == (ROOT / ".env.example").read_text()
    if os.environ.get("CMRT_IT_MODE") != "compose":
        pytest.skip("the `docker compose` lines run in the compose suite (`make test-compose`, "
                    "CMRT_IT_MODE=compose); the cp line ran")
    v2 = subprocess.run(["docker", "compose", "version"], capture_output=True,
                        timeout=60).returncode == 0
    port = _free_port()
    project = f"cmrt-readme-{uuid.uuid4().hex[:8]}"
    env = {**os.environ, "COMPOSE_PROJECT_NAME": project, "CMRT_API_PORT": str(port)}
    compose = "docker compose" if v2 else "docker-compose"
    try:
        for line in lines[1:]:
            cmd = _strip_comment(line).replace("docker compose", compose, 1)
            if " logs -f" in cmd:  # follows for ever: a few seconds of it
                try:
                    subprocess.run(["bash", "-c", cmd], cwd=ROOT, env=env, capture_output=True,
                                   text=True, timeout=5)
                except subprocess.TimeoutExpired as err:
                    out = (err.stdout or b"").decode(errors="replace")
                    assert "api" in out and "worker" in out, out[-2000:]
                continue
            p = _run(cmd, ROOT, env, timeout=1800)
            if cmd.endswith(" ps"):
                for svc in ("redis", "postgres", "api", "worker"):
                    assert svc in p.stdout, p.stdout
        t0 = time.monotonic()
        while True:  # the API container is healthy once /health answers
            try:
                health = httpx.get(f"http://127.0.0.1:{port}/health", timeout=3).json()
                if health["database"] == "ok" and health["broker"] == "ok":
                    break
            except httpx.HTTPError:
                pass
            assert time.monotonic() - t0 < 180, "the README's topology never answered /health"
            time.sleep(1)
        workers = _run(f"{compose} ps -q worker", ROOT, env).stdout.split()
        assert len(workers) == 4, workers
    finally:
        _run(f"{compose} down -v --timeout 10", ROOT, env, timeout=300)


def _wait_http(url: str, proc: subprocess.Popen, timeout: float = 90.0) -> None:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        assert proc.poll() is None, f"server exited {proc.returncode}"
        try:
            if httpx.get(url, timeout=2.0).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        time.sleep(0.3)
    raise AssertionError(f"{url} did not answer 200 within {timeout} s")


def _stop(proc: subprocess.Popen, timeout: float = 30.0) -> int:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    return proc.returncode


def _start(cmd: str, cwd: Path, env: dict[str, str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(["bash", "-c", f"exec {cmd}"], cwd=cwd, env=env,
                            stdout=log.open("wb"), stderr=subprocess.STDOUT,
                            start_new_session=True)


def test_cmrt_serve_embedded(scratch, tmp_path):
    line = next(_strip_comment(c) for c in readme_commands()
                if c.startswith(".venv/bin/cmrt serve"))
    port = _free_port()
    env = _env(CMRT_API_PORT=str(port), CMRT_DATA_DIR=str(tmp_path / "data"), CMRT_WORKERS="1")
    proc = _start(line, scratch, env, tmp_path / "serve.log")
    try:
        _wait_http(f"http://127.0.0.1:{port}/health", proc)
    finally:
        rc = _stop(proc)
    assert rc == 0, (tmp_path / "serve.log").read_text()[-3000:]
    assert (tmp_path / "data" / "cmrt.db").exists()


def test_client_commands(scratch, tmp_path):
    """submit / jobs / watch / library against `cmrt serve` (embedded), every form shown; the
    README's `URL` is the server's, `JOB` the first submitted job. The scratch folder's
    fast_bend.yaml has the tiny budget; bend_0.3 and bend_0.7 are submitted first so that
    the library queries find entries on either side of 0.5."""
    lines = [_strip_comment(c) for c in readme_commands()
             if c.split()[:2] in (
                 [".venv/bin/cmrt", "submit"], [".venv/bin/cmrt", "jobs"],
                 [".venv/bin/cmrt", "watch"], [".venv/bin/cmrt", "library"])
             or c.split()[:3] in ([".venv/bin/cmrt", "family", w]
                                  for w in ("submit", "show", "watch"))]
    assert [c.split()[1] for c in lines] == ["submit", "jobs", "watch", "library", "library",
                                             "library", "library", "family", "family", "family"]
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    # the family steps at each of the server's scans: every 0.2 s instead of 2 s
    env = _env(CMRT_API_PORT=str(port), CMRT_DATA_DIR=str(tmp_path / "data"), CMRT_WORKERS="1",
               CMRT_SCAN_INTERVAL="0.2")
    proc = _start(".venv/bin/cmrt serve", scratch, env, tmp_path / "serve.log")
    try:
        _wait_http(f"{url}/health", proc)
        cli_env = {**env, "CMRT_URL": url}
        for t in ("0.3", "0.7"):
            p = _run(f".venv/bin/cmrt submit bend_{t}.yaml --wait", scratch, cli_env)
            assert "library CMRT " in p.stdout
        out: dict[str, str] = {}
        job = family = None
        for line in lines:
            for form in _expand_optional(line):
                if job is not None:
                    form = form.replace(" JOB", f" {job}")
                if family is not None:
                    form = form.replace(" FAMILY", f" {family}")
                p = _run(form.replace("--url URL", f"--url {url}"), scratch, cli_env)
                out[form] = p.stdout
                if job is None and form.split()[1] == "submit":
                    job = re.match(r"job (\S+) ", p.stdout).group(1)
                if family is None and form.split()[1:3] == ["family", "submit"]:
                    family = re.match(r"family (\S+) ", p.stdout).group(1)
        waited = next(v for k, v in out.items() if k.endswith("--wait"))
        assert re.search(r"^gen +\d+  evals", waited, re.M) and "library CMRT " in waited
        watched = next(v for k, v in out.items() if k.split()[1] == "watch")
        assert f"job {job} stopped" in watched
        listed = next(v for k, v in out.items() if k.endswith("duration=0.3"))
        assert "duration=0.3" in listed and "duration=0.7" not in listed
        interp = json.loads(next(v for k, v in out.items() if k.endswith("duration=0.5 --json")))
        lo, hi = sorted(n["task_parameters"]["duration"] for n in interp["neighbours"])
        assert lo < 0.5 < hi  # 0.4 (fast_bend) or 0.3, and 0.7
        assert interp["source"] in ("interpolated", "member") and interp["members"]
        verified = next(v for k, v in out.items() if k.endswith("duration=0.5 --verify"))
        assert "simulated" in verified and "verdict" in verified
        assert json.loads((scratch / "answer.json").read_text())["knot_times"]
        refined = next(v for k, v in out.items() if k.split()[1:3] == ["library", "refine"]
                       and k.endswith("--wait"))
        assert "refinement job" in refined and "library CMRT " in refined
        grown = next(v for k, v in out.items() if k.split()[1:3] == ["family", "submit"])
        assert f"family {family} done" in grown and "| duration |" in grown
        shown = json.loads(next(v for k, v in out.items() if k.endswith(f"{family} --json")))
        assert [m["value"] for m in shown["members"]] == [0.3, 0.4, 0.5, 0.6]
        assert f"family {family} done" in next(
            v for k, v in out.items() if k.split()[1:3] == ["family", "watch"])
        _readme_characters(scratch, cli_env)
        _readme_python(scratch, url, cli_env)
    finally:
        rc = _stop(proc)
    assert rc == 0, (tmp_path / "serve.log").read_text()[-3000:]


def _readme_characters(d: Path, env: dict[str, str]) -> None:
    """The `cmrt characters` lines (add, then list and show), each distinct form once: the
    character is stored, listed and shown with its definition."""
    lines = [_strip_comment(c) for c in readme_commands()
             if c.split()[:2] == [".venv/bin/cmrt", "characters"]]
    forms = list(dict.fromkeys(f for line in lines for f in _expand_optional(line)))
    assert [f.split()[2] for f in forms][:1] == ["add"] and len(forms) >= 5, forms
    out = {form: _run(form, d, env).stdout for form in forms}
    assert "character my_character stored" in out[forms[0]]
    listed = next(v for k, v in out.items() if k.split()[2] == "list" and "--json" not in k)
    assert re.search(r"^my_character +stored +1\.793 +74\.97 +13 ", listed, re.M), listed
    shown = json.loads(next(v for k, v in out.items() if k.split()[2] == "show"
                            and k.endswith("--json")))
    assert shown["definition"] == yaml.safe_load((d / "examples" / "my_character.yaml")
                                                 .read_text())


def _readme_python(d: Path, url: str, env: dict[str, str]) -> None:
    """The README's ```python blocks, run as written against the server at `url` (the
    README's http://127.0.0.1:8000 is that server's address)."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert blocks, "the README shows no Python"
    for i, code in enumerate(blocks):
        script = d / f"readme_python_{i}.py"
        script.write_text(code.replace("http://127.0.0.1:8000", url))
        p = _run(f".venv/bin/python {script.name}", d, env)
        status = p.stdout.split()[0]
        assert status in ("converged", "stopped"), p.stdout


def _redis_db() -> str:
    return f"{REDIS}/{9 + uuid.uuid4().int % 6}"


def test_cmrt_worker(scratch, tmp_path):
    line = next(_strip_comment(c) for c in readme_commands()
                if c.startswith(".venv/bin/cmrt worker"))
    env = _env(CMRT_BROKER_URL=_redis_db(), CMRT_DATABASE_URL=f"sqlite:///{tmp_path}/w.db",
               CMRT_WORKER_CONCURRENCY="1")
    proc = _start(line, scratch, env, tmp_path / "worker.log")
    try:
        t0 = time.monotonic()
        while subprocess.run([str(VENV_BIN / "cmrt"), "worker", "--ping"], env=env,
                             capture_output=True, timeout=60).returncode != 0:
            assert proc.poll() is None, (tmp_path / "worker.log").read_text()[-3000:]
            assert time.monotonic() - t0 < 90, "the worker never answered a ping"
            time.sleep(0.2)
    finally:
        rc = _stop(proc)
    assert rc == 0, (tmp_path / "worker.log").read_text()[-3000:]


@pytest.fixture
def pg_url():
    from sqlalchemy import create_engine, text
    from sqlalchemy.engine import make_url

    admin = create_engine(PG_URL, connect_args={"connect_timeout": 3})
    try:
        with admin.connect() as c:
            c.execute(text("SELECT 1"))
    except Exception as err:  # noqa: BLE001
        admin.dispose()
        pytest.skip(f"PostgreSQL at {PG_URL} unreachable: {err}")
    schema = f"cmrt_readme_{uuid.uuid4().hex[:8]}"
    with admin.begin() as c:
        c.execute(text(f'CREATE SCHEMA "{schema}"'))
    url = make_url(PG_URL).update_query_dict({"options": f"-csearch_path={schema}"})
    yield url.render_as_string(hide_password=False)
    with admin.begin() as c:
        c.execute(text(f'DROP SCHEMA IF EXISTS "{schema}" CASCADE'))
    admin.dispose()


def _seed(api: str, scratch: Path) -> dict[str, str]:
    """Library entries the README's queries find: bends at 0.3-0.9 s, pushes of 200 and 400 N,
    a basis; tiny budgets. Returns JOB-independent ids for the README's variables."""
    fast = yaml.safe_load((scratch / "examples" / "fast_bend.yaml").read_text())
    push = yaml.safe_load((scratch / "examples" / "push.yaml").read_text())
    push["optimize"] = {**push.get("optimize", {}), **TINY}

    def set_force(d, force):
        for k, v in d.items():
            if k == "force":
                d[k] = force
            elif isinstance(v, dict):
                set_force(v, force)

    specs = [{**fast, "name": f"bend_{t}", "clip": {"preparation": 0.3, "duration": t,
                                                    "decay": 0.3}} for t in (0.3, 0.5, 0.7, 0.9)]
    for force in (200.0, 400.0):
        p = json.loads(json.dumps(push))
        p["name"] = f"push_{force:g}"
        set_force(p, force)
        specs.append(p)
    ids = []
    for spec in specs:
        r = httpx.post(f"{api}/jobs", json={"spec": spec}, timeout=30)
        assert r.status_code == 202, r.text
        ids.append(r.json()["id"])
    t0 = time.monotonic()
    for job_id in ids:
        while True:
            j = httpx.get(f"{api}/jobs/{job_id}", timeout=30).json()
            if j["status"] in ("converged", "stopped", "failed", "cancelled"):
                assert j["status"] in ("converged", "stopped"), j
                break
            assert time.monotonic() - t0 < 300, f"seed job {job_id} still {j['status']}"
            time.sleep(0.3)
    cmrt = httpx.get(f"{api}/jobs/{ids[0]}", timeout=30).json()["cmrt_id"]
    r = httpx.post(f"{api}/bases", json={"family": "bend", "k": 3}, timeout=60)
    assert r.status_code == 201, r.text
    (scratch / "spec.json").write_text(json.dumps(specs[1]))
    return {"CMRT": cmrt, "BASIS": r.json()["id"]}


def _first_job_shows_anticipation(api: str, job_id: str, timeout: float = 600.0) -> None:
    """The README's first job converges by its threshold to a standing CMRT better than the
    flat spline (it says: 144 evaluations, 1.0353 against 1.4424)."""
    t0 = time.monotonic()
    while (j := httpx.get(f"{api}/jobs/{job_id}", timeout=30).json())["status"] in (
            "queued", "running"):
        assert time.monotonic() - t0 < timeout, f"the first job still {j['status']}: {j}"
        time.sleep(0.2)
    assert j["status"] == "converged" and j["stop_rule"] == "threshold", j
    assert j["best_objective"] < j["spec"]["optimize"]["threshold"]
    entry = httpx.get(f"{api}/cmrts/{j['cmrt_id']}", timeout=30).json()
    assert entry["winner"] == "search" and not entry["fell"]
    assert entry["objective"] == j["best_objective"] < entry["objective_without"]
    assert not entry["fell_without"]
    print(f"README's first job: {j['evaluations']} evaluations, best {j['best_objective']:.4f},"
          f" flat spline {entry['objective_without']:.4f}")


def test_servers_and_every_curl(scratch, tmp_path, pg_url):
    cmds = readme_commands()
    port = _free_port()
    env = _env(CMRT_DATABASE_URL=pg_url, CMRT_BROKER_URL=_redis_db(), CMRT_WORKERS="1")
    exports = [c for c in cmds if c.startswith("export CMRT_")]
    assert {c.split("=")[0] for c in exports} == {"export CMRT_DATABASE_URL",
                                                 "export CMRT_BROKER_URL"}
    serve = next(_strip_comment(c) for c in cmds if c.startswith("cmrt serve --host"))
    worker = next(_strip_comment(c) for c in cmds if c.startswith("cmrt worker --concurrency"))
    assert serve.endswith(" &") and worker.endswith(" &")
    serve = serve[:-2].replace("--port 8000", f"--port {port}")  # 8000 may be taken
    procs = [_start(serve, scratch, env, tmp_path / "serve.log"),
             _start(worker[:-2], scratch, env, tmp_path / "worker.log")]
    api = f"http://127.0.0.1:{port}"
    try:
        _wait_http(f"{api}/health", procs[0])
        ids = _seed(api, scratch)
        curl_env = {**env, "API": api, **ids}
        statuses = {}
        wrap = ("curl() { command curl -w '\\nHTTP_STATUS %{http_code}\\n' \"$@\"; }; "
                "export -f curl; ")
        for c in cmds:
            if not c.startswith(("curl ", "python -c ", "open $API")):
                continue
            cmd = ("curl -s " + c[len("open "):]) if c.startswith("open ") else c
            line_env = curl_env
            if "/cancel" in c and "SLOW" in curl_env:  # spare the first job (see below)
                line_env = {**curl_env, "JOB": curl_env["SLOW"]}
            p = _run(wrap + cmd, scratch, line_env, timeout=120)
            codes = re.findall(r"HTTP_STATUS (\d+)", p.stdout)
            assert codes, f"{c!r}: no HTTP status in {p.stdout[-500:]}"
            code = int(codes[-1])
            statuses[c] = code
            if c.startswith("curl -s -X POST $API/jobs -H") and "JOB" not in curl_env:
                curl_env["JOB"] = json.loads(p.stdout.split("HTTP_STATUS")[0])["id"]
            if c.startswith("python -c ") and "slow_bend.yaml" in c:
                curl_env["SLOW"] = json.loads(p.stdout.split("HTTP_STATUS")[0])["id"]
            ok = {202, 409} if c.endswith("# 202; 409 if already finished") else range(200, 300)
            if c.endswith("# 200, or 409 until its first candidate"):
                ok = {200, 409}
            if c.endswith("# 200, or 404 until its first candidate"):
                ok = {200, 404}
            assert code in ok, f"{c!r} answered {code}: {p.stdout[-1500:]}"
        assert len(statuses) > 20, statuses  # every curl line of the README ran
        # leave nothing running: cancel what the README's submissions started, except the
        # first job, which must show anticipation working as the README says it does (so the
        # README's cancel line above was sent for the slow bend's job, the second one)
        assert "SLOW" in curl_env
        for j in httpx.get(f"{api}/jobs?limit=200", timeout=30).json()["items"]:
            if j["status"] in ("queued", "running") and j["id"] != curl_env["JOB"]:
                httpx.post(f"{api}/jobs/{j['id']}/cancel", timeout=30)
        _first_job_shows_anticipation(api, curl_env["JOB"])
    finally:
        rcs = [_stop(p) for p in procs]
    assert rcs == [0, 0], [(tmp_path / n).read_text()[-2000:] for n in ("serve.log",
                                                                       "worker.log")]


if __name__ == "__main__":  # pragma: no cover
    print("\n".join(readme_commands()))
    sys.exit(0)
