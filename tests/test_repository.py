"""The repository stands alone: no tracked file names an absolute path of one machine (a home,
root or work folder) or a folder beside the checkout. System paths every Debian machine has
(/usr/bin/chromium, /var/lib/docker) are not machine paths and are allowed."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: Folders of one machine or user, and the checkout's neighbours.
MACHINE_PATHS = r"/(work|root|home|Users|mnt)/|\.\./shared"


def test_no_tracked_file_names_a_machine_path():
    if shutil.which("git") is None:
        pytest.skip("no git to list the tracked files")
    inside = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--is-inside-work-tree"],
                            capture_output=True, text=True)
    if inside.stdout.strip() != "true":
        pytest.skip("not a git checkout (an unpacked copy): no tracked files to check")
    files = subprocess.run(["git", "-C", str(ROOT), "ls-files"], capture_output=True,
                           text=True, check=True).stdout.split()
    assert len(files) > 100 and "README.md" in files  # the listing is the checkout's
    p = subprocess.run(["git", "-C", str(ROOT), "grep", "-nIE", MACHINE_PATHS],
                       capture_output=True, text=True)
    assert p.returncode == 1, f"machine paths in tracked files:\n{p.stdout[:3000]}{p.stderr}"
