"""The family page (/dashboard/families/{id}) of a real family grown by `cmrt serve`: progress
while it runs, then members, every run's curve, the checks and the interpolation probes."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from dashboard_server import Server  # noqa: E402

#: A cheap real family: the quiet stance along its decay, 5 values, continuation from both ends.
FAMILY: dict[str, Any] = {
    "spec": {"name": "calm", "family": "calm", "task": {"type": "quiet_stance"},
             "clip": {"preparation": 0.4, "duration": 0.3, "decay": 0.8},
             "optimize": {"min_evaluations": 0, "window": 2, "improvement": 0.01,
                          "popsize": 4, "max_evaluations": 8}},
    "param": "clip.decay", "values": [0.8, 0.9, 1.0, 1.1, 1.2],
    "strategy": "continuation", "from": "both", "leave_out": [1.0],
    "warm": {"sigma0": 0.05, "window": 2, "max_evaluations": 4}, "k": 2, "seed": 1,
}
TIMEOUT_S = 300


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    srv = Server(tmp_path_factory.mktemp("family"))
    yield srv
    srv.stop()


def test_family_page_follows_a_family_to_its_checks(server, page):
    r = httpx.post(server.url + "/families", json=FAMILY, timeout=30)
    assert r.status_code == 202, r.text
    fam = r.json()
    page.goto(f"{server.url}/dashboard/families/{fam['id']}")
    page.wait_for_selector("body[data-state='loaded']", timeout=60_000)
    assert "calm along clip.decay" in page.locator("#title").text_content()
    assert page.locator("#runs tbody tr").count() == fam["runs"] - 1  # the probes are no job
    t0 = time.monotonic()
    while httpx.get(server.url + fam["url"], timeout=30).json()["status"] == "running":
        assert time.monotonic() - t0 < TIMEOUT_S, "the family did not finish"
        time.sleep(0.5)
    # the page polls until the family is done, without a reload
    deadline = time.monotonic() + 30
    while page.locator("#members tbody tr").count() != 5:
        assert time.monotonic() < deadline, "members never shown"
        time.sleep(0.2)
    values = [r.locator("td").first.text_content() for r in page.locator("#members tbody tr")
              .all()]
    assert values == ["0.8", "0.9", "1", "1.1", "1.2"]
    assert page.locator("#table2 tbody tr").count() == 1
    assert page.locator("#table2 tbody tr td").nth(4).text_content().endswith("%")
    assert page.locator("#probes tbody tr").count() == 3  # interior values
    assert page.locator("#curves canvas").count() == 1
    assert page.locator("#paper tbody tr").count() == 0  # no Table 2 in the paper for this
    assert page.get_attribute("#progress", "value") == page.get_attribute("#progress", "max")
    assert page.errors == []
