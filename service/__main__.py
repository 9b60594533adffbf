"""`python -m service [options]` is `cmrt serve [options]` (an entry point)."""

import sys

from cli.main import main

sys.exit(main(["serve", *sys.argv[1:]]))
