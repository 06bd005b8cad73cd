"""``python -m tak_thermo_ros.cli``: the same as ``tak_calib``."""

import sys

from tak_thermo_ros.cli import main

sys.exit(main())
