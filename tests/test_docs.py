"""The manual reads as a manual: README.md and the pages of docs/ (docs/history/ holds the
measurements log and is excluded from the size and heading rules).

  * no page names an absolute path of a machine or a file in a temporary directory, and no
    manual page has a date heading: a figure is the current one, its history is elsewhere;
  * the pages of docs/ together stay at most MAX_MANUAL_LINES long: a size a reader can hold
    (the README, the front door, is its own);
  * every link to another page of the repository points at a file that exists;
  * every command of a ```sh block is run: those of README.md, docs/cli.md and docs/api.md by
    tests/cli/test_readme.py (as written, with tiny budgets); those of the other pages here: a
    `cmrt` line is parsed by the `cmrt` command's own parser in every form it shows, with every
    file it names present; a `curl` line's path is a route of the API's OpenAPI document; a
    bench/ script answers --help. The few lines no test can run on one machine say why below.
"""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
#: Lines of docs/*.md together (the history excluded).
MAX_MANUAL_LINES = 2000
#: Pages whose ```sh blocks tests/cli/test_readme.py runs as written.
RUN_AS_WRITTEN = {ROOT / "README.md", DOCS / "cli.md", DOCS / "api.md"}
#: Commands that need what one test machine has not, and the test that covers what they do.
NOT_RUN = {
    "npx ": "the OpenAPI generator for TypeScript needs npm's registry and a Java runtime; "
            "tests/service/test_generated_client.py generates and uses the Python client",
    "docker run": "a worker host pointed at a central PostgreSQL and Redis; the compose suite "
                  "runs the same worker command (tests/integration/test_topology.py)",
    ".venv/bin/openapi-python-client": "tests/service/test_generated_client.py runs it",
}


def manual_pages() -> list[Path]:
    return [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]


def all_pages() -> list[Path]:
    return [*manual_pages(), *sorted((DOCS / "history").glob("*.md"))]


def test_no_page_names_an_absolute_path_or_a_temporary_file():
    bad = re.compile(r"(?<![\w.~])/(tmp|var/tmp|work|root|home|Users|mnt)/")
    found = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}"
             for p in all_pages() for i, line in enumerate(p.read_text().splitlines(), 1)
             if bad.search(line)]
    assert not found, "\n".join(found)


def test_no_manual_page_has_a_date_heading():
    dated = re.compile(r"^#+ .*\b20\d\d-\d\d(-\d\d)?\b")
    found = [f"{p.relative_to(ROOT)}:{i}: {line}" for p in manual_pages()
             for i, line in enumerate(p.read_text().splitlines(), 1) if dated.match(line)]
    assert not found, "\n".join(found)


def test_the_manual_is_a_size_a_reader_can_hold():
    sizes = {p.name: len(p.read_text().splitlines()) for p in manual_pages()[1:]}
    assert sum(sizes.values()) <= MAX_MANUAL_LINES, sizes


def test_every_link_between_pages_resolves():
    link = re.compile(r"\]\(([^)#\s]+)(#[^)]*)?\)")
    missing = []
    for p in all_pages():
        for target, _ in link.findall(p.read_text()):
            if "://" in target or target.startswith("mailto:"):
                continue
            if not (p.parent / target).exists():
                missing.append(f"{p.relative_to(ROOT)}: {target}")
    assert not missing, missing


def _commands(page: Path) -> list[str]:
    """The commands of a page's ```sh blocks, continuation lines joined, comments cut."""
    out = []
    for block in re.findall(r"```sh\n(.*?)```", page.read_text(), re.S):
        cur = ""
        for line in block.splitlines():
            part = line.rstrip(" \\")
            cur = f"{cur} {part}" if cur else part
            if line.endswith("\\"):
                continue
            try:
                shlex.split(cur, comments=True)
            except ValueError:
                continue
            cmd = re.sub(r"\s+#.*$", "", cur).strip()
            if cmd and not cmd.startswith("#"):
                out.append(" ".join(cmd.split()))
            cur = ""
    return out


def _checked_commands() -> list[tuple[str, str]]:
    return [(p.name, c) for p in manual_pages() if p not in RUN_AS_WRITTEN
            for c in _commands(p)]


def _forms(cmd: str) -> list[str]:
    """`a [--x | --y V]` -> ["a", "a --x", "a --y V"]."""
    base = re.sub(r"\s*\[.*$", "", cmd)
    forms = [base]
    for group in re.findall(r"\[([^\[\]]*)\]", cmd):
        forms += [f"{base} {alt.strip()}" for alt in group.split(" | ")]
    return forms


def test_every_command_of_the_other_pages_is_checked():
    """Each command is one of the kinds checked below or named in NOT_RUN."""
    kinds = ("cmrt ", ".venv/bin/cmrt ", "curl ", "python bench/", ".venv/bin/python bench/",
             "python -m bench.")
    unchecked = [f"{page}: {c}" for page, c in _checked_commands()
                 if not c.startswith(kinds) and not c.startswith(tuple(NOT_RUN))]
    assert not unchecked, unchecked


def test_cmrt_lines_parse_and_name_files_that_exist():
    from cli.main import build_parser

    parser = build_parser()
    checked = 0
    for page, cmd in _checked_commands():
        if not cmd.startswith(("cmrt ", ".venv/bin/cmrt ")):
            continue
        for form in _forms(cmd):
            argv = shlex.split(form)[1:]
            try:
                parser.parse_args(argv)
            except SystemExit as err:  # argparse's way of refusing
                pytest.fail(f"{page}: {form!r} does not parse ({err})")
            for arg in argv:
                if arg.startswith("examples/"):
                    assert (ROOT / arg).is_file(), f"{page}: {form!r} names {arg}"
            checked += 1
    assert checked >= 5


def test_curl_lines_name_routes_of_the_api(tmp_path):
    from cmrt.settings import Settings
    from service.app import create_app

    app = create_app(Settings(data_dir=tmp_path, database_url=f"sqlite:///{tmp_path}/d.db"),
                     run_drivers=False)
    paths = [*app.openapi()["paths"], "/openapi.json", "/docs"]  # the last two: FastAPI's own
    routes = [re.compile("^" + re.sub(r"\{[^}]+\}", "[^/]+", p) + "$") for p in paths]
    checked = 0
    for page, cmd in _checked_commands():
        if not cmd.startswith("curl "):
            continue
        url = next(w.strip("\"'") for w in shlex.split(cmd) if "$API" in w or "://" in w)
        path = re.sub(r"^(\$API|https?://[^/]+)", "", url).split("?")[0]
        path = re.sub(r"\$\{?\w+\}?", "ID", path)
        assert any(r.match(path) for r in routes), f"{page}: {cmd!r}: no route {path}"
        checked += 1
    assert checked >= 3


def test_bench_scripts_of_the_other_pages_answer_help():
    scripts = sorted({re.search(r"bench[/.](\w+)", c).group(1) for _, c in _checked_commands()
                      if "bench/" in c or "bench." in c})
    for name in scripts:
        p = subprocess.run([sys.executable, "-m", f"bench.{name}", "--help"], cwd=ROOT,
                           capture_output=True, text=True, timeout=120)
        assert p.returncode == 0 and "usage" in p.stdout.lower(), (name, p.stderr[-2000:])
