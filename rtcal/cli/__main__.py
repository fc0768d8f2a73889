"""``python -m rtcal.cli``."""

import sys

from rtcal.cli import main

sys.exit(main())
