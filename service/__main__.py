"""`python -m service [options]` is `cmrt serve [options]` (an entry point)."""

import sys

from service.command import main

sys.exit(main())
