"""Fixtures of the use-case tests: an empty repository on SQLite in the test's folder (a test
module that needs a library in it defines its own `repo`)."""

from __future__ import annotations

import pytest

from store import open_repository


@pytest.fixture
def repo(tmp_path):
    repo = open_repository(f"sqlite:///{tmp_path}/application.db")
    yield repo
    repo.engine.dispose()
