"""Unit-test fixtures of the service/worker layers: a migrated SQLite store per test and a
synthetic objective (tests/synthetic.py; fakes only here, never in the integration tests)."""

from __future__ import annotations

import pytest
from local_pool import local_executor as make_local_executor
from svc_helpers import LOCAL
from synthetic import Sphere

from cmrt.settings import Settings
from optim.executors import SerialExecutor
from store import open_repository


@pytest.fixture
def settings(tmp_path):
    return Settings(data_dir=tmp_path, database_url=f"sqlite:///{tmp_path}/t.db",
                    lease_seconds=2.0, max_attempts=2, workers=1)


@pytest.fixture
def config(settings):
    return settings.model_copy(update={"poll_interval": 0.02, "scan_interval": 0.1,
                                       "stall_timeout": 1.0, "broker_deadline": 2.0})


@pytest.fixture
def repo(settings):
    return open_repository(settings.database_url)


@pytest.fixture
def local_executor(config):
    ex = make_local_executor(config, SerialExecutor(), lambda spec: Sphere(centre=0.3))
    yield ex
    ex.close()


@pytest.fixture
def http_client(config, repo, local_executor):
    """The app with the job drivers off (jobs are stored, not run): HTTP-layer tests."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    with TestClient(create_app(config, repo=repo, executor=local_executor,
                               run_drivers=False), base_url=LOCAL) as c:
        yield c


@pytest.fixture
def client(config, repo, local_executor):
    """The app with its job drivers on: jobs run the synthetic objective (local_executor),
    while simulations and replays are real clips in the API's own pool. A test module that
    wants the HTTP layer alone overrides `client` with `http_client`."""
    from fastapi.testclient import TestClient

    from service.app import create_app

    with TestClient(create_app(config, repo=repo, executor=local_executor),
                    base_url=LOCAL) as c:
        yield c
