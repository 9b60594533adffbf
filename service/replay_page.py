"""One self-contained replay HTML file from a replay document (`sim.replay.build_replay`).

`render_replay(doc)` inlines the document (JSON), the player (`static/replay/replay.js`,
`replay.css`) and uPlot (`static/vendor/uplot/`) into `static/replay/replay.html`: the file
opens from file:// with the network off. Its Content-Security-Policy (a `<meta>` in the file,
and the `Content-Security-Policy` header the service sends with it, `replay_csp`) allows
exactly those inline scripts and styles by their SHA-256 hashes and nothing else: no network,
no other script. User text in the document cannot close the data `<script>`: every `<` of the
JSON is written `\\u003c`.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from typing import Any

_PLACEHOLDER = re.compile(r"@([A-Z_]+)@")


@dataclass(frozen=True)
class _Assets:
    template: str
    uplot_js: str
    uplot_css: str
    replay_js: str
    replay_css: str


@lru_cache(maxsize=1)
def _assets() -> _Assets:
    static = resources.files("service").joinpath("static")
    rp, up = static.joinpath("replay"), static.joinpath("vendor", "uplot")
    return _Assets(template=rp.joinpath("replay.html").read_text(),
                   uplot_js=up.joinpath("uPlot.iife.min.js").read_text(),
                   uplot_css=up.joinpath("uPlot.min.css").read_text(),
                   replay_js=rp.joinpath("replay.js").read_text(),
                   replay_css=rp.joinpath("replay.css").read_text())


def _sha256(text: str) -> str:
    return "'sha256-" + base64.b64encode(hashlib.sha256(text.encode()).digest()).decode() + "'"


def _policy(a: _Assets) -> str:
    scripts = " ".join(_sha256(s) for s in (a.uplot_js, a.replay_js))
    styles = " ".join(_sha256(s) for s in (a.uplot_css, a.replay_css))
    return (f"default-src 'none'; script-src {scripts}; style-src {styles}; "
            "img-src 'none'; base-uri 'none'; form-action 'none'")


def replay_csp() -> str:
    """The Content-Security-Policy header of a served replay page (the file's, plus no
    framing)."""
    return _policy(_assets()) + "; frame-ancestors 'none'"


def data_json(doc: dict[str, Any]) -> str:
    """The document as compact JSON safe inside a `<script>` element (no `<` in it)."""
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).replace("<", "\\u003c")


def render_replay(doc: dict[str, Any]) -> str:
    """The self-contained HTML player of `doc` (a `sim.replay` document)."""
    a = _assets()
    values = {"CSP": _policy(a), "SCHEMA": str(doc.get("schema", "")).replace("<", ""),
              "DATA": data_json(doc), "UPLOT_CSS": a.uplot_css, "REPLAY_CSS": a.replay_css,
              "UPLOT_JS": a.uplot_js, "REPLAY_JS": a.replay_js}
    # One pass over the template: text substituted in is never scanned for placeholders.
    return _PLACEHOLDER.sub(lambda m: values[m.group(1)], a.template)
