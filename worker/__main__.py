"""`python -m worker [options]` is `cmrt worker [options]` (an entry point)."""

import sys

from worker.command import main

sys.exit(main())
