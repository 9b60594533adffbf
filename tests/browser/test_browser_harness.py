"""The browser harness itself: the vendored plotting library draws offline with no errors."""

from __future__ import annotations

from pathlib import Path

UPLOT = Path(__file__).resolve().parents[2] / "service" / "static" / "vendor" / "uplot"


def test_vendored_uplot_draws_offline(offline_page, tmp_path):
    html = tmp_path / "plot.html"
    html.write_text(
        "<!doctype html><html><head><meta charset=utf-8>"
        f"<style>{(UPLOT / 'uPlot.min.css').read_text()}</style>"
        f"<script>{(UPLOT / 'uPlot.iife.min.js').read_text()}</script></head><body>"
        "<div id=p></div><script>"
        "const u = new uPlot({width: 400, height: 200, series: [{}, {label: 'y'}]},"
        " [[0, 1, 2], [1, 4, 9]], document.getElementById('p'));"
        "document.title = 'drawn ' + u.data[1].length;"
        "</script></body></html>")
    offline_page.goto(html.as_uri())
    assert offline_page.title() == "drawn 3"
    assert offline_page.locator("#p canvas").count() == 1
    assert offline_page.errors == []


def test_page_errors_are_collected(page, tmp_path):
    html = tmp_path / "bad.html"
    html.write_text("<!doctype html><script>console.error('boom'); undefinedCall();</script>")
    page.goto(html.as_uri())
    assert any("boom" in e for e in page.errors)
    assert any("undefinedCall" in e for e in page.errors)
