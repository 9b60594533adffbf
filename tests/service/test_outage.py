"""A database outage on the real PostgreSQL server: every route that reads or writes the
database answers 503 JSON `{"detail": ...}` with `Retry-After` (never a 500 text/plain), the
writes refused during it leave nothing behind, and the service answers normally once the
database takes connections again.

The outage is made on a fresh database of the test server (`CMRT_TEST_POSTGRES_URL`, default
postgresql+psycopg://postgres@127.0.0.1:5432/test): `ALTER DATABASE ... ALLOW_CONNECTIONS
false` (superusers included) and every session of it terminated, so the pool's connections die
and new ones are refused, as when the server restarts or an operator locks it.
"""

from __future__ import annotations

import os
import uuid

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import create_engine, text
from sqlalchemy.engine import make_url
from svc_helpers import LOCAL, bend_spec, wait_job

from service.app import create_app
from store import open_repository

PG_URL = os.environ.get(
    "CMRT_TEST_POSTGRES_URL", "postgresql+psycopg://postgres@127.0.0.1:5432/test")

pytestmark = pytest.mark.postgres


@pytest.fixture
def pg_database():
    """(admin engine, URL) of a fresh database on the test server, dropped at the end."""
    admin = create_engine(PG_URL, isolation_level="AUTOCOMMIT",
                          connect_args={"connect_timeout": 3})
    try:
        with admin.connect() as c:
            c.execute(text("SELECT 1"))
    except Exception as err:  # noqa: BLE001 - any failure means "unreachable"
        admin.dispose()
        pytest.skip(f"PostgreSQL at {PG_URL} unreachable ({type(err).__name__})")
    name = f"cmrt_outage_{os.getpid()}_{uuid.uuid4().hex[:8]}"
    with admin.connect() as c:
        c.execute(text(f'CREATE DATABASE "{name}"'))
    url = make_url(PG_URL).set(database=name).render_as_string(hide_password=False)
    try:
        yield admin, name, url
    finally:
        with admin.connect() as c:
            c.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        admin.dispose()


def _outage(admin, name: str, on: bool) -> None:
    with admin.connect() as c:
        c.execute(text(f'ALTER DATABASE "{name}" ALLOW_CONNECTIONS {"false" if on else "true"}'))
        if on:
            c.execute(text("SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                           "WHERE datname = :n AND pid <> pg_backend_pid()"), {"n": name})


def test_a_database_outage_answers_503_json_and_writes_nothing(pg_database, config,
                                                                local_executor):
    admin, name, url = pg_database
    settings = config.model_copy(update={"database_url": url})
    repo = open_repository(url)
    app = create_app(settings, repo=repo, executor=local_executor)  # drivers on
    with TestClient(app, base_url=LOCAL) as c:
        done = c.post("/jobs", json={"spec": bend_spec("before")}).json()["id"]
        job = wait_job(c, done)
        cmrt = job["cmrt_id"]
        assert cmrt, job
        done_status = job["status"]

        _outage(admin, name, on=True)
        probes = [("GET", "/jobs", None), ("GET", f"/jobs/{done}", None),
                  ("GET", f"/jobs/{done}/generations", None),
                  ("GET", f"/jobs/{done}/evaluations", None), ("GET", f"/jobs/{done}/best", None),
                  ("GET", "/cmrts", None), ("GET", f"/cmrts/{cmrt}", None),
                  ("GET", "/cmrts?family=bend&duration=0.3", None), ("GET", "/bases", None),
                  ("GET", "/bases/nosuchbasis", None),
                  ("POST", "/jobs", {"spec": bend_spec("during")}),
                  ("POST", f"/jobs/{done}/cancel", None),
                  ("POST", "/bases", {"family": "bend", "k": 1}),
                  ("POST", "/links", {"path": f"/jobs/{done}/replay"}),
                  ("HEAD", "/jobs", None)]
        for method, path, body in probes:
            r = c.request(method, path, json=body)
            assert r.status_code == 503, (method, path, r.status_code, r.text)
            assert int(r.headers["retry-after"]) >= 1, (method, path)
            if method != "HEAD":
                assert r.headers["content-type"] == "application/json", (method, path)
                assert r.json() == {"detail": "database: unreachable; retry later"}, r.text
        health = c.get("/health")
        assert health.status_code == 503 and health.headers["retry-after"]
        assert health.json()["database"] == "error"
        assert health.json()["detail"] == "database: unreachable"
        assert "postgres" not in health.text and "5432" not in health.text

        _outage(admin, name, on=False)
        jobs = c.get("/jobs").json()
        assert jobs["total"] == 1 and jobs["items"][0]["id"] == done, jobs
        after = c.get(f"/jobs/{done}").json()
        assert after["status"] == done_status and after["cancel_requested"] is False
        assert c.get("/bases").json()["total"] == 0
        assert c.get("/health").status_code == 200
        again = c.post("/jobs", json={"spec": bend_spec("after")})
        assert again.status_code == 202, again.text
        assert wait_job(c, again.json()["id"])["status"] in ("converged", "stopped")
    repo.engine.dispose()
