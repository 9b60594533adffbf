"""`cmrt serve` bound to every interface: the Host allowlist of a served process (uvicorn, real
sockets) and the start-up warning when only loopback names would be answered."""

from __future__ import annotations

import os
import socket
import subprocess
import time
from pathlib import Path

import httpx
import pytest
from proc_helpers import stop_group

ROOT = Path(__file__).resolve().parents[2]
CMRT = ROOT / ".venv" / "bin" / "cmrt"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(tmp_path: Path, env_extra: dict[str, str]) -> tuple[subprocess.Popen, int, Path]:
    port = _free_port()
    log = tmp_path / "serve.log"
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update({"CMRT_DATA_DIR": str(tmp_path / "data"), "CMRT_WORKERS": "1", **env_extra})
    proc = subprocess.Popen([str(CMRT), "serve", "--host", "0.0.0.0", "--port", str(port)],
                            env=env, cwd=tmp_path, stdout=log.open("wb"),
                            stderr=subprocess.STDOUT, start_new_session=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        assert proc.poll() is None, log.read_text()
        try:
            if httpx.get(f"http://127.0.0.1:{port}/health", timeout=2).status_code == 200:
                return proc, port, log
        except httpx.TransportError:
            time.sleep(0.2)
    stop_group(proc)
    raise AssertionError(f"cmrt serve did not answer: {log.read_text()}")


@pytest.mark.parametrize("named", [False, True])
def test_wildcard_bind_answers_allowed_names_only(tmp_path, named):
    proc, port, log = _serve(tmp_path, {"CMRT_ALLOWED_HOSTS": "cmrt.lan"} if named else {})
    try:
        base = f"http://127.0.0.1:{port}"
        for host in (f"localhost:{port}", f"127.0.0.1:{port}"):
            assert httpx.get(base + "/jobs", headers={"host": host}).status_code == 200
        rebound = {"host": f"evil.example:{port}", "origin": f"http://evil.example:{port}",
                   "sec-fetch-site": "same-origin"}
        for r in (httpx.get(base + "/jobs", headers=rebound),
                  httpx.post(base + "/bases", json={"family": "bend"}, headers=rebound)):
            assert r.status_code == 400 and r.json()["detail"].startswith("host: "), r.text
        lan = httpx.get(base + "/jobs", headers={"host": f"cmrt.lan:{port}"})
        assert lan.status_code == (200 if named else 400)
    finally:
        stop_group(proc)
    warned = "serve: bound to every interface (0.0.0.0) but neither CMRT_PUBLIC_URL nor " \
             "CMRT_ALLOWED_HOSTS is set" in log.read_text()
    assert warned is not named, log.read_text()
