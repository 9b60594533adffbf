"""The dashboard's replay link with a token set and reads closed, in a real Chromium against a
real `cmrt serve`: the plain link answers 401 (a followed link sends no header); clicking it
on the job page fetches a signed link (POST /links) and opens the replay page."""

from __future__ import annotations

import sys
from pathlib import Path

import httpx
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from dashboard_server import Server, long_job  # noqa: E402

from store import open_repository  # noqa: E402

TOKEN = "browser-s3cret"
#: Most time a page may take to load before the test gives up, ms (not a measurement).
LOAD_TIMEOUT_MS = 90_000


@pytest.fixture(scope="module")
def closed_server(tmp_path_factory):
    data = tmp_path_factory.mktemp("signed")
    repo = open_repository(f"sqlite:///{data}/cmrt.db")
    job_id = long_job(repo, 2, popsize=4)
    repo.engine.dispose()
    srv = Server(data, workers=1, env_extra={"CMRT_API_TOKEN": TOKEN})
    srv.job_id = job_id
    try:
        yield srv
    finally:
        srv.stop()


def test_replay_link_opens_with_a_signed_url(closed_server, page):
    srv = closed_server
    plain = f"{srv.url}/jobs/{srv.job_id}/replay"
    assert httpx.get(plain, timeout=30).status_code == 401
    page.goto(f"{srv.url}/dashboard/jobs/{srv.job_id}")
    page.fill("#token", TOKEN)
    page.press("#token", "Enter")  # `change`: stored in sessionStorage, page reloaded
    page.wait_for_selector("#token[placeholder='(token set)']", timeout=LOAD_TIMEOUT_MS)
    page.errors.clear()  # the first load's data requests, sent before the token: 401s
    page.wait_for_selector("#replay-link", timeout=LOAD_TIMEOUT_MS)
    assert page.locator("#error").is_hidden(), page.locator("#error").text_content()
    assert page.get_attribute("#replay-link", "href") == f"/jobs/{srv.job_id}/replay"
    with page.expect_navigation(timeout=LOAD_TIMEOUT_MS):
        page.click("#replay-link")
    assert page.url.startswith(plain + "?expires=") and "&signature=" in page.url
    page.wait_for_selector("#replay[data-ready=true]", timeout=LOAD_TIMEOUT_MS)
    assert page.errors == []
    # The signed URL opens nothing else: the job's JSON with its query is still refused.
    query = page.url.split("?", 1)[1]
    assert httpx.get(f"{srv.url}/jobs/{srv.job_id}?{query}", timeout=30).status_code == 401


def test_motion_link_downloads_with_a_signed_url(closed_server, page):
    """The job page's BVH link, with reads closed: the click signs the path and the browser
    downloads the file (a plain GET answers 401)."""
    srv = closed_server
    plain = f"{srv.url}/jobs/{srv.job_id}/motion.bvh"
    assert httpx.get(plain, timeout=30).status_code == 401
    page.goto(f"{srv.url}/dashboard/jobs/{srv.job_id}")
    page.fill("#token", TOKEN)
    page.press("#token", "Enter")
    page.wait_for_selector("#token[placeholder='(token set)']", timeout=LOAD_TIMEOUT_MS)
    page.errors.clear()
    page.wait_for_selector("#motion-bvh", timeout=LOAD_TIMEOUT_MS)
    with page.expect_download(timeout=LOAD_TIMEOUT_MS) as dl:
        page.click("#motion-bvh")
    assert dl.value.url.startswith(plain + "?expires=") and "&signature=" in dl.value.url
    text = Path(dl.value.path()).read_text()
    assert text.startswith("HIERARCHY\nROOT pelvis\n") and "\nMOTION\nFrames: " in text
    assert page.errors == []
