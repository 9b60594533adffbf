"""A client generated from the served OpenAPI document by openapi-python-client (the most used
Python generator; offline, a dev dependency) covers every route of the document, and its typed
calls do the whole round trip against a real `cmrt serve` (embedded default: SQLite file, local
process pool of 1, real simulations of short bends): submit jobs, wait for them, find their
CMRTs in the library, interpolate, build a PCA basis, grow a family."""

from __future__ import annotations

import importlib
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from proc_helpers import free_port, stop_group, tiny_bend

ROOT = Path(__file__).resolve().parents[2]
BIN = ROOT / ".venv" / "bin"
#: The generated package's name (a folder of the test's temporary directory).
PACKAGE = "cmrt_generated_client"
#: 2 generations of 4 candidates of a 0.8 s clip: well under a second of CPU each.
TINY = {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0}
TERMINAL = {"converged", "stopped", "failed", "cancelled"}
#: A cheap real family: the quiet stance along its decay (4 values, continuation from both
#: ends, one left out of the checks' basis).
CALM = {"name": "calm", "family": "calm", "task": {"type": "quiet_stance"},
        "clip": {"preparation": 0.3, "duration": 0.2, "decay": 0.4},
        "optimize": {"popsize": 4, "max_evaluations": 4, "min_evaluations": 0, "window": 2}}


def bend(name: str, duration: float) -> dict[str, Any]:
    return tiny_bend(name, duration, TINY)


def _free_port() -> int:
    return free_port()


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """A running `cmrt serve` on a loopback port, and the client package generated from its
    /openapi.json (imported as PACKAGE)."""
    tmp = tmp_path_factory.mktemp("generated")
    port = _free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("CMRT_")}
    env.update({"CMRT_DATA_DIR": str(tmp / "data"), "CMRT_WORKERS": "1",
                "CMRT_API_PORT": str(port), "CMRT_LOG_LEVEL": "WARNING"})
    log = tmp / "serve.log"
    proc = subprocess.Popen([str(BIN / "cmrt"), "serve"], env=env, cwd=tmp,
                            stdout=log.open("wb"), stderr=subprocess.STDOUT,
                            start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        t0 = time.monotonic()
        while True:
            assert proc.poll() is None, log.read_text()[-3000:]
            try:
                if httpx.get(f"{url}/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert time.monotonic() - t0 < 90, "cmrt serve did not become healthy"
            time.sleep(0.2)
        doc = httpx.get(f"{url}/openapi.json", timeout=10).json()
        (tmp / "openapi.json").write_text(json.dumps(doc))
        gen = subprocess.run(
            [str(BIN / "openapi-python-client"), "generate", "--path", str(tmp / "openapi.json"),
             "--output-path", str(tmp / PACKAGE), "--meta", "none"],
            capture_output=True, text=True, timeout=300, cwd=tmp,
            env={**env, "PATH": f"{BIN}{os.pathsep}{env.get('PATH', '')}"})
        assert gen.returncode == 0, gen.stdout + gen.stderr
        # every schema and every endpoint generated: the generator says nothing was dropped
        assert "Warning" not in gen.stdout + gen.stderr, gen.stdout + gen.stderr
        sys.path.insert(0, str(tmp))
        yield doc, tmp / PACKAGE, url
    finally:
        if str(tmp) in sys.path:
            sys.path.remove(str(tmp))
        stop_group(proc)


def _module_name(operation_id: str) -> str:
    """The generator's module name of an operation id (snake case)."""
    return re.sub(r"[^a-z0-9]+", "_", re.sub(r"(?<=[a-z0-9])([A-Z])", r"_\1",
                                            operation_id)).lower()


def test_every_route_of_the_document_is_generated(served):
    doc, package, _url = served
    operations = [(path, method, op) for path, item in doc["paths"].items()
                  for method, op in item.items()]
    assert len(operations) >= 28  # every route: jobs, families, library, replays, operations
    generated = {p.stem: p for p in (package / "api").glob("*/*.py") if p.stem != "__init__"}
    ids = [op["operationId"] for _, _, op in operations]
    assert len(set(ids)) == len(ids)
    for path, method, op in operations:
        # short ids from the router's tag and the function's name (e.g. jobs_cancel_job)
        assert op["operationId"] == f"{op['tags'][0]}_{op['operationId'].split('_', 1)[1]}"
        assert len(op["operationId"]) <= 40, op["operationId"]
        source = generated.pop(_module_name(op["operationId"])).read_text()
        assert f'"method": "{method}"' in source and f'"url": "{path}"' in source, (method, path)
        # every JSON success answer is a typed model, never an untyped dict
        for code, resp in op["responses"].items():
            schema = (resp.get("content") or {}).get("application/json", {}).get("schema")
            if int(code) < 300 and schema is not None and path != "/cmrts/interpolate":
                assert "$ref" in schema, (method, path, code, schema)
    assert generated == {}  # and nothing else
    names = doc["components"]["schemas"]
    assert not [n for n in names if "__" in n]  # no module-path names


def _wait_job(api: Any, client: Any, job_id: str, timeout: float = 120) -> Any:
    t0 = time.monotonic()
    while True:
        job = api.jobs_get_job.sync(job_id, client=client)
        if job.status in TERMINAL:
            return job
        assert time.monotonic() - t0 < timeout, f"job {job_id} still {job.status}"
        time.sleep(0.2)


def test_the_generated_client_does_the_round_trip(served):
    _doc, _package, url = served
    pkg = importlib.import_module(PACKAGE)
    m = importlib.import_module(f"{PACKAGE}.models")
    api = type("Api", (), {
        name: importlib.import_module(f"{PACKAGE}.api.{tag}.{tag}_{name.split('_', 1)[1]}")
        for tag, names in {
            "jobs": ["jobs_submit_job", "jobs_get_job"],
            "library": ["library_find_cmrts", "library_get_cmrt", "library_interpolate_cmrt",
                        "library_create_basis"],
            "families": ["families_submit_family", "families_get_family"],
            "operations": ["operations_health"],
        }.items() for name in names})
    with pkg.Client(base_url=url, raise_on_unexpected_status=True,
                    timeout=httpx.Timeout(30.0)) as client:
        assert isinstance(api.operations_health.sync(client=client), m.Health)
        # jobs: the typed envelope, with the spec as a typed TaskSpec
        jobs = {}
        for t in (0.3, 0.5):
            body = m.JobRequest(spec=m.TaskSpec.from_dict(bend(f"gen_{t}", t)), seed=1)
            accepted = api.jobs_submit_job.sync(client=client, body=body)
            assert isinstance(accepted, m.JobAccepted), accepted
            assert accepted.budget.evaluations == 8 + 4 - 1 + 2
            jobs[t] = accepted.id
        done = {t: _wait_job(api, client, j) for t, j in jobs.items()}
        for job in done.values():
            assert isinstance(job, m.JobOut) and job.status == "stopped", job
            assert job.evaluations == 8 and isinstance(job.cmrt_id, str)
        # the library: each job's CMRT found by its task parameter, read back typed
        for t, job in done.items():
            page = api.library_find_cmrts.sync(
                client=client, family="bend",
                task_parameters=m.LibraryFindCmrtsTaskParameters.from_dict({"duration": t}))
            assert isinstance(page, m.CmrtPage)
            assert [c.id for c in page.items] == [job.cmrt_id]
            cmrt = api.library_get_cmrt.sync(job.cmrt_id, client=client)
            assert isinstance(cmrt, m.CmrtOut) and cmrt.source.job_id == job.id
            assert cmrt.clip.duration == t and len(cmrt.knot_times) == len(cmrt.values) == 4
        # interpolation between the two
        between = api.library_interpolate_cmrt.sync_detailed(
            client=client, family="bend",
            task_parameters=m.LibraryInterpolateCmrtTaskParameters.from_dict({"duration": 0.4}))
        assert between.status_code == 200, between.content
        answer = json.loads(between.content)
        assert {n["id"] for n in answer["neighbours"]} == {j.cmrt_id for j in done.values()}
        # a PCA basis of the family's CMRTs
        basis = api.library_create_basis.sync(client=client,
                                              body=m.BasisRequest(family="bend", k=1))
        assert isinstance(basis, m.BasisOut), basis
        assert sorted(basis.members) == sorted(j.cmrt_id for j in done.values())
        assert basis.k == 1 and len(basis.components) == 1
        assert basis.variance_explained[0] == pytest.approx(1.0)  # two members: one direction
        # a family, followed to its end
        family = m.FamilySpec.from_dict({
            "spec": CALM, "param": "clip.decay", "values": [0.4, 0.5, 0.6, 0.7],
            "strategy": "continuation", "from": "both", "leave_out": [0.5], "k": 2,
            "warm": {"max_evaluations": 4, "window": 2}})
        accepted = api.families_submit_family.sync(client=client, body=family)
        assert isinstance(accepted, m.FamilyAccepted), accepted
        t0 = time.monotonic()
        while True:
            fam = api.families_get_family.sync(accepted.id, client=client)
            assert isinstance(fam, m.FamilyOut)
            if fam.status in ("done", "failed", "cancelled"):
                break
            assert time.monotonic() - t0 < 240, f"family still {fam.status}"
            time.sleep(0.5)
        assert fam.status == "done", fam.error
        assert [row["value"] for row in fam.members] == [0.4, 0.5, 0.6, 0.7]
        assert all(run.job_id is not None for run in fam.runs)
