"""Adds to a wheelhouse the requirements its wheels have under another Python version.

`pip wheel` evaluates environment markers (`python_full_version < "3.11.3"`) for the Python
running it; an image's Python may differ (Debian bookworm's is 3.11.2). This reads every
wheel's Requires-Dist, evaluates the markers for `python_full_version` = the given version
(requirements of extras left out: those pip already resolved, the same for any version), and
builds the missing ones with `pip wheel --no-deps`, until nothing is missing.

    python wheelhouse_fill.py WHEELHOUSE PYTHON_VERSION [CONSTRAINTS]
"""

from __future__ import annotations

import re
import subprocess
import sys
import zipfile
from pathlib import Path

from packaging.markers import default_environment
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name


def requirements(wheel: Path) -> list[Requirement]:
    with zipfile.ZipFile(wheel) as z:
        meta = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
        text = z.read(meta).decode()
    return [Requirement(m) for m in re.findall(r"^Requires-Dist: (.+)$", text, re.M)]


def have(house: Path) -> set[str]:
    return {canonicalize_name(w.name.split("-")[0]) for w in house.glob("*.whl")}


def main(house: Path, version: str, constraints: str | None = None) -> int:
    env = {**default_environment(), "python_full_version": version,
           "python_version": ".".join(version.split(".")[:2]), "extra": ""}
    while True:
        present = have(house)
        missing = sorted({str(r.name) + str(r.specifier) for w in house.glob("*.whl")
                          for r in requirements(w)
                          if canonicalize_name(r.name) not in present
                          and (r.marker is None or r.marker.evaluate(env))})
        if not missing:
            return 0
        print(f"wheelhouse: for Python {version}, adding {', '.join(missing)}")
        cmd = [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--wheel-dir",
               str(house), *missing]
        subprocess.run(cmd + (["-c", constraints] if constraints else []), check=True)


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1]), sys.argv[2], *sys.argv[3:4]))
