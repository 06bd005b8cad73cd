"""``tak_calib``, the offline tool: one module per command, the shared options in one place.

``tak_calib = tak_thermo_ros.cli:main`` (setup.cfg); :mod:`tak_thermo_ros.cli.tak_calib` builds
the parser from the command modules and runs one.
"""

from __future__ import annotations

import os

# Small least-squares problems on a 2-core machine run fastest single-threaded; competing
# OpenBLAS threads made `diagnose` up to 8x slower. Set before numpy loads; a user's value wins.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

from tak_thermo_ros.cli.tak_calib import build_parser, main  # noqa: E402

__all__ = ['build_parser', 'main']
