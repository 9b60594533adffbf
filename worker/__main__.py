"""`python -m worker [options]` is `cmrt worker [options]` (an entry point)."""

import sys

from cli.main import main

sys.exit(main(["worker", *sys.argv[1:]]))
