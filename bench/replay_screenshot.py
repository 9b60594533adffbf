"""A PNG of a replay file at a chosen time, in Debian's headless Chromium with the network off.

Usage: .venv/bin/python bench/replay_screenshot.py REPLAY.html --at 1.45 --out docs/img/x.png
Opens the self-contained file (`cmrt simulate ... --replay REPLAY.html`), seeks the player to
`--at` seconds and saves the page; prints the file's size, the frame shown and any console
error (there should be none).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from playwright.sync_api import sync_playwright

CHROMIUM = os.environ.get("CMRT_CHROMIUM", "/usr/bin/chromium")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("replay", type=Path)
    ap.add_argument("--at", type=float, default=0.0, help="clip time (s) to show")
    ap.add_argument("--out", type=Path, required=True, help="PNG path")
    ap.add_argument("--width", type=int, default=1280)
    args = ap.parse_args()
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        ctx = browser.new_context(viewport={"width": args.width, "height": 900}, offline=True)
        page = ctx.new_page()
        errors: list[str] = []
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(f"{args.replay.resolve().as_uri()}?t={args.at}")
        page.wait_for_selector("#replay[data-ready=true]")
        args.out.parent.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(args.out), full_page=True)
        frame = page.get_attribute("#replay", "data-frame")
        browser.close()
    print(json.dumps({"replay": str(args.replay), "bytes": args.replay.stat().st_size,
                      "frame": int(frame), "png": str(args.out), "console_errors": errors}))


if __name__ == "__main__":
    main()
