"""The optional libraries: imported only by the commands that need them, named when missing.

They have no rosdep key, so ``package.xml`` cannot declare them and ``rosdep install`` does not
bring them: a robot that only runs the node never needs them. A command that does need one calls
:func:`require` first, which turns a missing library into one line naming the pip package.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from tak_thermo_ros.errors import DependencyError

OPTIONAL = {
    'dask': 'dask[distributed]',
    'distributed': 'dask[distributed]',
    'statsmodels': 'statsmodels',
    'allantools': 'allantools',
    'pyulog': 'pyulog',
    'pymavlink': 'pymavlink',
}
"""Module -> pip package of each optional library (no rosdep key; listed in docs/manual.md).

``pyulog`` reads PX4 ULogs; ``pymavlink`` serves the tests and benchmarks only (the reference
DataFlash reader; the package reads ``.bin`` files itself)."""


def require(module: str, command: str) -> ModuleType:
    """Import the optional ``module`` for ``command``.

    :raises DependencyError: one line naming the pip package, when it is not installed.
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as error:
        if (error.name or '').split('.')[0] != module.split('.')[0]:
            raise  # installed, but broken: its own error says what is wrong
        package = OPTIONAL.get(module.split('.')[0], module)
        msg = f"{command} needs the optional Python package {package}: pip install '{package}'"
        raise DependencyError(msg) from None
