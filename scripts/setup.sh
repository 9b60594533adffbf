#!/usr/bin/env bash
# Idempotent set-up on a fresh Debian bookworm machine: PyODE from Debian, a .venv with the
# project, and only the `ode` module of Debian's dist-packages visible in it.
#   scripts/setup.sh          what `make run` needs: the product and its runtime dependencies
#   scripts/setup.sh --test   what `make test` needs besides: the dev extras (pytest, ruff,
#                             schemathesis, playwright, the generated-client tool, bvh),
#                             Chromium and Blender
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
TEST=0
[ "${1:-}" = "--test" ] && TEST=1

# A package registry that does not answer for a while (a name that does not resolve, a reset
# connection) must not fail a fresh machine's set-up: each download step is retried after
# 30, 60 and 120 s before set-up gives up. pip and apt already retry single requests; this
# covers an outage longer than their own few seconds of retries.
retry() {
    local wait=30 attempt=1
    until "$@"; do
        if [ "$attempt" -ge 4 ]; then
            echo "setup: '$*' failed $attempt times; giving up" >&2
            return 1
        fi
        echo "setup: '$*' failed (attempt $attempt); retrying in ${wait}s" >&2
        sleep "$wait"
        attempt=$((attempt + 1)); wait=$((wait * 2))
    done
}
ODE_SO_GLOB="/usr/lib/python3/dist-packages/ode.cpython-311-*.so"

if ! compgen -G "$ODE_SO_GLOB" >/dev/null; then
    echo "setup: installing Debian's python3-pyode"
    SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo
    retry $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive retry $SUDO apt-get install -y -qq python3-pyode libode-dev >/dev/null
fi

# The browser tests drive Debian's Chromium through playwright: playwright's own browser
# download needs a host that package-only networks do not reach.
if [ "$TEST" = 1 ] && [ ! -x /usr/bin/chromium ]; then
    echo "setup: installing Debian's chromium"
    SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo
    retry $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive retry $SUDO apt-get install -y -qq chromium chromium-driver >/dev/null
fi

# The BVH export's check opens the exported file in Blender (tests/sim/test_blender.py): Debian's
# blender, headless; the test path only (`make run` never needs it).
if [ "$TEST" = 1 ] && ! command -v blender >/dev/null; then
    echo "setup: installing Debian's blender"
    SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo
    retry $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive retry $SUDO apt-get install -y -qq --no-install-recommends \
        blender >/dev/null
fi

if [ ! -x .venv/bin/python ]; then
    echo "setup: creating .venv"
    "$PY" -m venv .venv
fi

# Expose only the ode extension module (not all of Debian's dist-packages) through a folder
# holding a link to it, named in a .pth file.
SITE=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
mkdir -p .venv/pyode
ln -sf $(compgen -G "$ODE_SO_GLOB" | head -1) .venv/pyode/
echo "$(pwd)/.venv/pyode" > "$SITE/pyode.pth"

STAMP=.venv/.installed
if [ ! -f "$STAMP" ] || [ pyproject.toml -nt "$STAMP" ]; then
    echo "setup: installing the project into .venv"
    retry .venv/bin/pip install -q --upgrade pip
    retry .venv/bin/pip install -q -e .
    touch "$STAMP"
fi
TEST_STAMP=.venv/.installed-test
if [ "$TEST" = 1 ] && { [ ! -f "$TEST_STAMP" ] || [ pyproject.toml -nt "$TEST_STAMP" ]; }; then
    echo "setup: installing the test extras into .venv"
    retry .venv/bin/pip install -q -e '.[dev]'
    touch "$TEST_STAMP"
fi
.venv/bin/python -c 'import ode, numba, cma' || { echo "setup: imports failed" >&2; exit 1; }
