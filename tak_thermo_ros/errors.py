"""The exceptions users see: one base class, one subclass per concern.

Every message names the thing that is wrong (file, key, topic) in one line; the command-line
tools print it without a traceback and exit non-zero.
"""

from __future__ import annotations


class TakError(Exception):
    """Base of every error raised on purpose by tak_thermo_ros.

    ``reason``: the message without the prefix that names where it arose, when an error is
    raised again with one (:func:`tak_thermo_ros.passes.run.prefixed`); else ``None``.
    """

    reason: str | None = None


class CalibrationError(TakError):
    """A calibration (parameters YAML or in-memory values) is invalid."""


class ScenarioError(TakError):
    """A simulator scenario is invalid."""


class FitError(TakError):
    """The data cannot determine the requested model (ill-posed fit)."""


class BagError(TakError):
    """A bag cannot be read or written as the bag contract requires."""


class LogError(TakError):
    """A delimited (CSV) log cannot be imported into the bag contract."""


class CdrError(BagError):
    """A raw CDR message is malformed or truncated (``index``: its position, counted from 0)."""

    def __init__(self, message: str, index: int) -> None:
        super().__init__(message)
        self.index = index


class OutputError(TakError):
    """An output cannot be written where asked (a special file, an existing output, a full disk)."""


class EffectError(TakError):
    """A user-defined effect raised or returned values that are not finite or of a wrong shape."""


class NoiseError(TakError):
    """A noise model, its data (Allan variance) or its file (Kalibr-style imu.yaml) is invalid."""


class DependencyError(TakError):
    """An optional library that a command needs is not installed (the message names its pip package)."""


class CarrierError(TakError):
    """A record of the carrier method's stages (or its model) is unusable: NaN, gauss-sized numbers, no turn."""


class FlightLogError(TakError):
    """A flight log (a PX4 ULog, an ArduPilot DataFlash ``.bin``) cannot be read as a record."""
