"""The options of a hand-held fit (:class:`HandheldSettings`), as the fit, a pool and a fleet's prior pass them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tak_thermo_ros.core.fit.link_uncertainty import HeldSpreads
from tak_thermo_ros.core.fit.prior import CurvePrior
from tak_thermo_ros.core.values import STANDARD_GRAVITY


@dataclass(frozen=True)
class HandheldSettings:
    """The options of a hand-held fit.

    :param effects: per sensor, offset effects to fit beyond the paper's link (names, as ``--effects``).
    :param axis_orders: per sensor the offset polynomial's order per axis x y z, at most ``bias_order``
        (the terms beyond held at 0; a pool's orders chosen by leaving whole records out); ``None``: ``bias_order``.
    :param variances: a pool's variances per sensor, ``(turn-on spread (3,), rests' extra (3,))``, taken as
        given instead of their REML (the folds of the order's choice).
    :param turns: use the turns (``False``: the rests alone).
    :param prior: what units of its kind say about the curve (:mod:`~tak_thermo_ros.core.fit.prior`): its rows
        join the solve, and the fit stands in its basis, at its orders, over its temperatures too.
    :param held_spreads: a held term's spread where the records do not bound it (the file's uncertainty).
    """

    bias_order: int = 3
    scale_order: int = 2
    temp_code_ref: float | None = None
    gravity: float = STANDARD_GRAVITY
    latitude: float | None = None
    effects: dict[str, tuple] = field(default_factory=dict)
    axis_orders: dict[str, tuple[int, int, int]] | None = None
    variances: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
    turns: bool = True
    prior: CurvePrior | None = None
    held_spreads: HeldSpreads = HeldSpreads()
