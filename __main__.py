"""``python -m fluidsense``: the same command line as ``fluidsense``."""

import sys

from fluidsense.cli import main

sys.exit(main())
