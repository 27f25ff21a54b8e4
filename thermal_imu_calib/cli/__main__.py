"""``python -m thermal_imu_calib.cli``: the command line, as the console script runs it.

The calibrator node draws its HTML report this way, in a child process.
"""

import sys

from .entry import main

sys.exit(main())
