"""A bounded schemathesis run against the served OpenAPI document (part of `make test`).

The app runs under uvicorn on a fresh SQLite database (tests/service/fuzz_server.py: a small
library built first, then the job drivers off, so fuzzed jobs are stored but start nothing).
schemathesis runs every check (`--checks all`) in its coverage, fuzzing and stateful phases
(and the examples phase on the documented examples) with a fixed seed: no server error, no
response that breaks the document. It runs twice: on the open API, and on the API closed by
CMRT_API_TOKEN (reads closed too) with the token sent, where schemathesis' `ignored_auth` check
also sends each operation without it and expects a 401. The two runs go side by side, each
against its own server (one fixture for the module; each test checks its run). The figures are
printed (pytest -s) and written to `schemathesis-figures.json` in each run's temporary folder.

`FUZZ_DRIVERS=on` serves the app with its job drivers on (every accepted job optimised for real
while the fuzzer goes on), `FUZZ_MAX_EXAMPLES=N` sets the cases per operation and phase:
`bench/fuzz_api.sh` runs both ways at a larger size.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import pytest

HERE = Path(__file__).parent
#: Test cases per operation and phase: bounds the run (about 10,900 cases, 70 s of CPU between
#: schemathesis and the server, 70-80 s of wall time at load 2-3 on this machine; a busy machine
#: stretches the wall time, not the CPU time).
MAX_EXAMPLES = int(os.environ.get("FUZZ_MAX_EXAMPLES", "100"))
#: The job drivers of the served app: off (jobs stored, nothing started) unless FUZZ_DRIVERS=on.
DRIVERS = os.environ.get("FUZZ_DRIVERS", "off") == "on"
#: The run is killed (and the test fails) once schemathesis and the server together have used
#: this much CPU (the work done, whatever the machine's load: about 4 times the run's)...
MAX_CPU_SECONDS = 300 * max(1, MAX_EXAMPLES // 100) * (3 if DRIVERS else 1)
#: ... or once neither has used any CPU for this long (a request that hangs), ...
STALL_SECONDS = 120
#: ... or past this wall time whatever it is (a last resort; the CPU limits come first).
MAX_SECONDS = 8 * MAX_CPU_SECONDS


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _cpu_seconds(pgids: set[int], seen: dict[int, float]) -> float:
    """CPU time (user + system, with reaped children) of every process in the process groups
    `pgids` since the first call with `seen`, s: `seen` keeps each process' last figure, so
    a process that has ended still counts."""
    tick = os.sysconf("SC_CLK_TCK")
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_bytes().rsplit(b")", 1)[1].split()
        except OSError:  # the process ended meanwhile
            continue
        if int(fields[2]) in pgids:  # fields from the state: pgrp is the 3rd, utime the 12th
            seen[int(stat.parent.name)] = sum(int(f) for f in fields[11:15]) / tick
    return sum(seen.values())


def _run_bounded(cmd: list[str], cwd: Path, server_pgid: int) -> tuple[int | None, str, str]:
    """Run `cmd` (in a process group of its own) until it exits, or kill it past the CPU
    limit, a stall or the wall limit (see MAX_CPU_SECONDS); returns (code, stdout, stderr),
    code None when it was killed."""
    out, err = (cwd / "schemathesis.out").open("w+"), (cwd / "schemathesis.err").open("w+")
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=out, stderr=err, start_new_session=True)
    groups = {proc.pid, server_pgid}
    t0 = last_move = time.monotonic()
    seen: dict[int, float] = {}
    cpu0 = used = _cpu_seconds(groups, seen)
    why = None
    try:
        while proc.poll() is None:
            time.sleep(1.0)
            now, cpu = time.monotonic(), _cpu_seconds(groups, seen) - cpu0
            if cpu > used:
                used, last_move = cpu, now
            if used > MAX_CPU_SECONDS:
                why = f"used {used:.0f} s of CPU (limit {MAX_CPU_SECONDS} s)"
            elif now - last_move > STALL_SECONDS:
                why = f"no CPU used for {STALL_SECONDS} s (a hung request?)"
            elif now - t0 > MAX_SECONDS:
                why = f"ran {now - t0:.0f} s (limit {MAX_SECONDS} s)"
            if why:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    out.seek(0), err.seek(0)
    stdout, stderr = out.read(), err.read()
    out.close(), err.close()
    print(f"schemathesis: {time.monotonic() - t0:.0f} s, {used:.0f} s of CPU with the server"
          f" (load {os.getloadavg()[0]:.1f})")
    return (None if why else proc.returncode), stdout, (why or "") + "\n" + stderr


def _schemathesis() -> list[str]:
    exe = Path(sys.executable).with_name("schemathesis")
    if exe.exists():
        return [str(exe)]
    found = shutil.which("schemathesis")
    if not found:
        pytest.fail("schemathesis is not installed (it is in the dev extras: make setup)")
    return [found]


#: The bearer token of the closed-API run.
TOKEN = "fuzz-token"


#: The two runs: the open API, and the API closed by the token (reads too).
MODES = ("open", "token")


@contextlib.contextmanager
def _served(mode: str, tmp_path: Path) -> Iterator[tuple[str, dict[str, str], list[str], int]]:
    """The served app: open, or closed by CMRT_API_TOKEN (reads too); yields (url, ids,
    extra schemathesis arguments, the server's process group)."""
    port = _free_port()
    log = (tmp_path / "server.log").open("w")
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    extra: list[str] = []
    if mode == "token":
        env["CMRT_API_TOKEN"] = TOKEN
        extra = ["-H", f"Authorization: Bearer {TOKEN}"]
    proc = subprocess.Popen(
        [sys.executable, str(HERE / "fuzz_server.py"), str(tmp_path), str(port),
         *(["drivers"] if DRIVERS else [])],
        stdout=subprocess.PIPE, stderr=log, text=True, env=env,
        start_new_session=True)  # its own process group: every process it forks ends with it
    try:
        line = proc.stdout.readline()
        assert line, f"fuzz_server.py exited: {(tmp_path / 'server.log').read_text()[-2000:]}"
        ids = json.loads(line)
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 30
        while True:
            try:
                if httpx.get(url + "/health", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert time.monotonic() < deadline, "the server did not answer /health in 30 s"
            time.sleep(0.2)
        yield url, ids, extra, proc.pid
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=10)
        with contextlib.suppress(ProcessLookupError):  # pool processes it left behind
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        log.close()


def _fuzz(tmp_path: Path, served: tuple) -> dict[str, Any]:
    """One schemathesis run against `served`: its exit code, output and report (None when it
    wrote none)."""
    url, ids, extra, server_pgid = served
    config = (HERE / "schemathesis.toml.in").read_text()
    for k, v in ids.items():
        config = config.replace(f"@{k}@", v)
    (tmp_path / "schemathesis.toml").write_text(config)
    report = tmp_path / "report.json"
    cmd = [*_schemathesis(), "--config-file", str(tmp_path / "schemathesis.toml"), "run",
           f"{url}/openapi.json", "--checks", "all", "--max-examples", str(MAX_EXAMPLES),
           *extra, "--report", "json", "--report-json-path", str(report)]
    code, stdout, stderr = _run_bounded(cmd, tmp_path, server_pgid)
    return {"url": url, "tmp": tmp_path, "code": code, "stdout": stdout, "stderr": stderr,
            "report": json.loads(report.read_text()) if report.exists() else None}


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory) -> Iterator[dict[str, dict[str, Any]]]:
    """Both runs, each against its own server, side by side (each is a client and a server
    taking turns, about one CPU: together they use both of the machine's); the servers
    answer until the module's tests are done. Runs by mode."""
    dirs = {m: tmp_path_factory.mktemp(f"fuzz-{m}") for m in MODES}
    with contextlib.ExitStack() as stack, ThreadPoolExecutor(len(MODES)) as pool:
        starting = {m: _served(m, dirs[m]) for m in MODES}
        started = {m: pool.submit(c.__enter__) for m, c in starting.items()}
        for c in starting.values():  # each server stopped at the end, or if another failed
            stack.push(c)  # (the pool exits first: every start has ended by then)
        served = {m: f.result() for m, f in started.items()}
        runs = {m: pool.submit(_fuzz, dirs[m], served[m]) for m in MODES}
        runs = {m: f.result() for m, f in runs.items()}
        yield runs


@pytest.mark.parametrize("mode", MODES)
def test_schemathesis_all_checks(fuzzed, mode):
    run = fuzzed[mode]
    url, tmp_path, code, stdout, stderr = (run[k] for k in ("url", "tmp", "code", "stdout",
                                                             "stderr"))
    assert code is not None, f"schemathesis killed: {stderr[-2000:]}\n{stdout[-4000:]}"
    assert run["report"] is not None, stdout[-4000:] + stderr[-2000:]
    r = run["report"]
    accepted = {op: sum(p["accepted"] for p in phases.values())
                for op, phases in r["valid_rates"].items()}
    figures = {
        "operations": r["operations"],
        "test_cases": r["test_cases"],
        "phases": {k: v["status"] for k, v in r["phases"].items()},
        "drivers": "on" if DRIVERS else "off",
        "max_examples": MAX_EXAMPLES,
        "failures": len(r["failures"]),
        "errors": len(r["errors"]),
        "running_time_s": round(r["running_time"], 1),
        "accepted_positive_cases": accepted,
        "warnings": {k: v for k, v in r["warnings"].items() if v},
    }
    (tmp_path / "schemathesis-figures.json").write_text(json.dumps(figures, indent=1))
    print("schemathesis figures:", json.dumps(figures, indent=1))
    assert code == 0 and not r["failures"] and not r["errors"], stdout[-6000:]
    doc = httpx.get(f"{url}/openapi.json", timeout=30).json()
    operations = sum(len(item) for item in doc["paths"].values())  # every documented one
    assert operations >= 20
    assert r["operations"]["tested"] == r["operations"]["selected"] == operations
    assert r["test_cases"]["generated"] > 1000 and r["test_cases"]["with_failures"] == 0
    assert all(r["phases"][p]["status"] == "success" for p in ("coverage", "fuzzing",
                                                                "stateful"))
    assert accepted["POST /jobs"] > 0, "the documented example spec was not accepted"
    assert accepted["POST /jobs/{job_id}/cancel"] > 0, "the queued job was not cancelled"
    assert accepted["GET /families/{family_id}"] > 0, "the seeded family was not found"
    assert accepted["POST /families/{family_id}/cancel"] > 0, "the family was not cancelled"
