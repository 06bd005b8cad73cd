"""The learned file: what the calibration watch learned, as a calibration file every command reads.

``-p learn:=true -p learned_file:=PATH`` makes the node write it (atomically, outside the
message path: periodically and at shutdown) and read it at its next start. It is a calibration
file (``tak_calib validate``, ``diagnose`` and ``export`` take it as ``--params``): the original
calibration with the learned gyroscope corrections folded into its curve
(:func:`~tak_thermo_ros.core.link.watch.learned_unit`), plus a ``learned`` parameter beside
``calibration`` holding the corrections, their variances and a digest of the original curve, so
that the next run goes on from them and never applies them to another calibration.
"""

from __future__ import annotations

import os

from tak_thermo_ros.core.link.model import UnitCalibration
from tak_thermo_ros.core.link.watch import LearnedState, calibration_digest, check_learned, learned_unit
from tak_thermo_ros.errors import TakError
from tak_thermo_ros.formats.calibration_file import LEARNED_KEY, load_unit_parameters, save_unit  # noqa: F401


def save_learned(path: str | os.PathLike[str], original: UnitCalibration, state: LearnedState, *,
                 source: str = '') -> None:
    """Write the learned file atomically (validated by a round trip through the calibration parser)."""
    header = (f'What the compensator\'s calibration watch learned at the rests of {state.runs} runs ({state.rests} '
              f'rests)\non top of {source or "the original calibration"} (never overwritten). A calibration '
              f'file: tak_calib validate / diagnose / export read it.')
    save_unit(path, learned_unit(original, state), header=header, extra_parameters={LEARNED_KEY: state.to_mapping()})


def load_learned(path: str | os.PathLike[str], unit: UnitCalibration | None = None) -> LearnedState | None:
    """The learning's state in a learned file, or ``None`` when the file does not exist.

    :param unit: the calibration the node applies it on: its corrections are judged against the bounds
        learning keeps on it (:func:`~tak_thermo_ros.core.link.watch.check_learned`), unless they were
        learned on another calibration
        (then they are not applied: learning starts afresh).
    :raises TakError: one line naming the file, when it exists but is no learned file, or its corrections
        lie beyond the bounds.
    """
    loaded = load_unit_parameters(path, missing_ok=True)
    if loaded is None:
        return None
    parameters = loaded[1]
    if LEARNED_KEY not in parameters:
        msg = f'{path}: a calibration file without a {LEARNED_KEY} section: not a learned file (give another path)'
        raise TakError(msg)
    state = LearnedState.from_mapping(parameters[LEARNED_KEY], f'{path}: {LEARNED_KEY}')
    applies = unit is not None and (not state.original or state.original == calibration_digest(unit))
    if applies:
        check_learned(unit, state, str(path))  # type: ignore[arg-type]
    return state
