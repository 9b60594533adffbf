"""The replay file of the fast bend in a real Chromium: `cmrt simulate examples/fast_bend.yaml
--cmrt R --replay OUT.html --compare` with R from a real (tiny) optimisation. It opens from
file:// with the network off and no console error, play advances the frame, the scrubber moves
the figure (the current frame attribute and the canvas pixels), its size is under 1 MB; user
text in a document is shown as text, never run."""

from __future__ import annotations

import base64
import hashlib
import json
import time
from pathlib import Path

import pytest
import yaml

from cli.main import main

ROOT = Path(__file__).resolve().parents[2]
MAX_BYTES = 1_000_000
#: How long play may take to show frame 6 (0.06 s of clip at 1x) on a loaded machine.
PLAY_WAIT_S = 20.0
#: A real CMRT on a small budget: one seed, two generations of four.
TINY = {"popsize": 4, "max_evaluations": 8, "min_evaluations": 0}


@pytest.fixture(scope="module")
def fast_bend_replay(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("replay")
    spec = yaml.safe_load((ROOT / "examples" / "fast_bend.yaml").read_text())
    spec["optimize"] = {**spec["optimize"], **TINY}
    (d / "fast_bend.yaml").write_text(yaml.safe_dump(spec))
    assert main(["optimize", str(d / "fast_bend.yaml"), "--workers", "1", "--seed", "1",
                 "--out", str(d / "fast.json")]) == 0
    out = d / "fast_bend.html"
    assert main(["simulate", str(d / "fast_bend.yaml"), "--cmrt", str(d / "fast.json"),
                 "--replay", str(out), "--compare"]) == 0
    return out


def _canvas_hash(page, k: int) -> str:
    url = page.eval_on_selector(f"canvas.stage[data-clip='{k}']", "c => c.toDataURL()")
    return hashlib.sha256(base64.b64decode(url.split(",", 1)[1])).hexdigest()


def _frame(page) -> int:
    return int(page.get_attribute("#replay", "data-frame"))


def test_size_under_a_megabyte(fast_bend_replay, record_property):
    size = fast_bend_replay.stat().st_size
    record_property("replay_bytes", size)
    print(f"fast bend replay, compare mode (2 clips of 2.6 s at 100 frames/s): {size} bytes")
    assert size < MAX_BYTES


def test_opens_offline_plays_and_scrubs(offline_page, fast_bend_replay):
    page = offline_page
    page.goto(fast_bend_replay.as_uri())
    page.wait_for_selector("#replay[data-ready=true]")
    assert page.locator("canvas.stage").count() == 2  # compare: flat spline and the CMRT
    captions = page.locator("figure.view figcaption").all_inner_texts()
    assert captions[0].startswith("no anticipation") and captions[1].startswith("with the CMRT")
    assert page.locator(".plots .uplot").count() == 3
    assert _frame(page) == 0
    # Play: the frame advances by itself.
    page.click("#play")
    # Polled from here: the page's CSP forbids the string evaluation wait_for_function uses.
    deadline = time.monotonic() + PLAY_WAIT_S
    while _frame(page) <= 5 and time.monotonic() < deadline:
        page.wait_for_timeout(50)
    assert _frame(page) > 5, "the frame did not advance on play"
    page.click("#play")  # pause
    assert page.get_attribute("#replay", "data-playing") == "false"
    # Scrub: to the start, then into the bend; the frame and the drawn figure follow.
    page.eval_on_selector("#scrub", "s => { s.value = 0; s.dispatchEvent(new Event('input')); }")
    assert _frame(page) == 0
    before = [_canvas_hash(page, k) for k in (0, 1)]
    page.eval_on_selector("#scrub",
                          "s => { s.value = 125; s.dispatchEvent(new Event('input')); }")
    assert _frame(page) == 125 and page.get_attribute("#replay", "data-time") == "1.250"
    after = [_canvas_hash(page, k) for k in (0, 1)]
    assert before[0] != after[0] and before[1] != after[1]
    # Speed and loop controls are there with the range.
    speeds = page.eval_on_selector_all("#speed option", "os => os.map(o => Number(o.value))")
    assert min(speeds) == 0.1 and max(speeds) == 2
    assert page.is_checked("#loop")
    assert page.errors == []


def test_the_motion_downloads_from_the_file(offline_page, fast_bend_replay):
    """Each clip's BVH and CSV download from the file itself (offline, under its CSP): the
    files `cmrt simulate --export` writes of the same clip."""
    page = offline_page
    page.goto(fast_bend_replay.as_uri())
    page.wait_for_selector("#replay[data-ready=true]")
    doc = json.loads(fast_bend_replay.read_text().split('type="application/json">', 1)[1]
                     .split("</script>", 1)[0])
    for k, stem in ((0, "fast_bend_flat"), (1, "fast_bend_cmrt")):
        for fmt in ("bvh", "csv"):
            with page.expect_download() as dl:
                page.click(f"a.download-{fmt}[data-clip='{k}']")
            assert dl.value.suggested_filename == f"{stem}.{fmt}"
            assert Path(dl.value.path()).read_text() == doc["clips"][k]["motion"][fmt]
    d = fast_bend_replay.parent
    assert main(["simulate", str(d / "fast_bend.yaml"), "--cmrt", str(d / "fast.json"),
                 "--export", str(d / "fast.bvh")]) == 0
    assert (d / "fast.bvh").read_text() == doc["clips"][1]["motion"]["bvh"]
    assert page.errors == []


def test_user_text_is_shown_not_run(page, tmp_path):
    from service.replay_page import render_replay
    from sim import parse_spec
    from sim.replay import ReplayClip, build_replay
    from sim.rollout import evaluate

    spec = parse_spec({"name": "quiet", "clip": {"preparation": 0.1, "duration": 0.1,
                                                  "decay": 0.1},
                       "task": {"type": "quiet_stance"}})
    evil = "</script><script>window.pwned = 1</script><img src=x onerror=window.pwned=2>"
    doc = build_replay(spec, [ReplayClip(evil, evaluate(spec, None, traces=True))])
    html = tmp_path / "evil.html"
    html.write_text(render_replay(doc))
    page.goto(html.as_uri())
    page.wait_for_selector("#replay[data-ready=true]")
    assert page.evaluate("window.pwned === undefined")
    assert page.locator("figure.view figcaption strong").inner_text() == evil
    assert page.errors == []


def test_served_replay_runs_under_its_csp_header(page, tmp_path):
    """`POST /simulations/replay` answers the page with a hash-only Content-Security-Policy
    header; in the browser, under that header, the player still draws with no CSP error."""
    from fastapi.testclient import TestClient

    from cmrt.settings import Settings
    from service.app import create_app

    settings = Settings(data_dir=tmp_path, database_url=f"sqlite:///{tmp_path}/t.db", workers=1)
    spec = {"name": "quiet", "clip": {"preparation": 0.2, "duration": 0.2, "decay": 0.2},
            "task": {"type": "quiet_stance"}}
    with TestClient(create_app(settings, run_drivers=False), base_url="http://localhost") as c:
        r = c.post("/simulations/replay", json={"spec": spec})
    assert r.status_code == 200, r.text
    csp = r.headers["content-security-policy"]
    url = "http://replay.test/simulations/replay"
    page.route(url, lambda route: route.fulfill(
        status=200, body=r.text, headers={"content-type": "text/html; charset=utf-8",
                                          "content-security-policy": csp}))
    page.goto(url)
    page.wait_for_selector("#replay[data-ready=true]")
    assert page.locator("canvas.stage").count() == 1
    assert page.errors == []
