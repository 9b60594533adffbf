#!/usr/bin/env bash
# schemathesis over the whole API with every check, open and closed by a token (sent), with the
# job drivers ON: every job the fuzzer gets accepted is optimised for real (ODE, local process
# pool) while the fuzzer goes on (tests/service/test_schemathesis.py; `make test` runs it with
# the drivers off). Figures: results/fuzz_api/*/schemathesis-figures.json.
#
#     bash bench/fuzz_api.sh [MAX_EXAMPLES (default 100)] [off]
set -euo pipefail
cd "$(dirname "$0")/.."
rm -rf results/fuzz_api && mkdir -p results
FUZZ_DRIVERS="${2:-on}" FUZZ_MAX_EXAMPLES="${1:-100}" .venv/bin/python -m pytest \
    tests/service/test_schemathesis.py -q -s -p no:cacheprovider --basetemp=results/fuzz_api
