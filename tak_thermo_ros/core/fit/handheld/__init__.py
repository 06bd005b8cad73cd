"""The fit of a hand-held record: both sensors' links from still intervals and turns, no table.

A unit turned by hand has no recorded reference, but two things are known (Tedaldi et al.,
ICRA 2014, imu_tk; Basalt's ``calib_bias.hpp``): at rest the specific force has the magnitude
of local gravity and the rate is zero (or the Earth's), and a turn between two rests carries the
gravity direction seen before it onto the one seen after it. This package fits the paper's link
per axis (offset ``b(T)``, scale ``K(T)``) and the triad's misalignment (the ``cross_axis``
effect) of both sensors from those facts, with the same columns as every other fit
(:func:`~tak_thermo_ros.core.fit.design.axis_design`), the same solve from a triangular factor
(:class:`~tak_thermo_ros.core.fit.solve.BlockedQR`, :func:`~tak_thermo_ros.core.fit.solve.solve_factor`)
and the same model (:func:`~tak_thermo_ros.core.fit.model.calibration_from`,
:func:`~tak_thermo_ros.core.fit.model.finish_fit`, the residual through the one correction path).
The effects' shapes are searched by :func:`~tak_thermo_ros.core.fit.fit_model` itself on the
still samples with the reference the hand-held fit found.

**Accelerometer.** At rest ``N_s = M(T_s) g u_k + b(T_s) + noise`` with ``u_k`` the unknown up
direction of still interval ``k`` (two angles) and ``M = diag(K0 F_c(T)) + C``. Gauss-Newton on
the axes' parameters and every ``u_k`` together, the ``u_k`` eliminated interval by interval
(the rows projected onto the complement of their two columns), the axes weighted by their noise:
the errors of the parameters carry the unknown directions. Only ``|f|`` and relative
directions are known, so a rotation of the sensor frame is unobservable: three couplings are held
at zero (the *gauge*, as Basalt's lower-triangular matrix): ``c_xy = c_xz = c_yz = 0``, the
corrected x axis is the accelerometer's x sensitive axis and the corrected y axis lies in the
plane of its x and y axes.

**Gyroscope.** At rest ``N_s = M(T_s) omega_ref + b(T_s) + noise`` (``omega_ref`` zero, or the
Earth rate's vertical component along ``u_k`` at ``latitude``). A turn from interval ``a`` to
``b`` integrates the corrected rate (trapezoid rule) to ``R``, which must carry ``u_b`` onto
``u_a``: two rows ``E_a^T R u_b = 0`` per turn, linearised in the parameters through the
rotation's Jacobian (:func:`~tak_thermo_ros.core.rotation.integrate_segments`), weighted by
their predicted covariance (the gyroscope's white noise over the turn, the directions' errors).
All nine terms of the gyroscope's matrix are fitted: it is tied to the accelerometer's frame.
The accelerations of a turn (a lever arm) never enter: only still samples and rates are used.

**What a record cannot determine is held and said.** A term is held (scale 1, every other term
0) when the record does not determine it to within
:data:`~tak_thermo_ros.core.fit.handheld.system.BOUNDS` (or not at all), in the order of
:data:`~tak_thermo_ros.core.fit.handheld.system.HOLD_ORDER`; each held group is one line and a
note in the file. A temperature span narrower than
:data:`~tak_thermo_ros.core.fit.handheld.held.SPAN_PER_ORDER_C` per polynomial order lowers the
orders (a span under that holds every thermal term: offsets, scales and misalignment at one
temperature).

**The rooms.** This ``__init__`` names the package's public API (the names the rest of the
package, the tests and the benches use: ``from tak_thermo_ros.core.fit.handheld import
fit_handheld``); each lives in one of the modules:

- :mod:`~tak_thermo_ros.core.fit.handheld.settings`: the fit's options (:class:`HandheldSettings`);
- :mod:`~tak_thermo_ros.core.fit.handheld.layout`: one sensor's joint parameter vector and design;
- :mod:`~tak_thermo_ros.core.fit.handheld.system`: the solve with held terms (the triangular
  factor of a sensor's rows, the holds, what a solve gives);
- :mod:`~tak_thermo_ros.core.fit.handheld.rests`: a sensor's still samples compressed rest by rest;
- :mod:`~tak_thermo_ros.core.fit.handheld.accel`: the accelerometer's problem (the up directions
  eliminated, the gauge);
- :mod:`~tak_thermo_ros.core.fit.handheld.gyro`: the gyroscope's problem (its rests and turns);
- :mod:`~tak_thermo_ros.core.fit.handheld.pooled`: a pool of records, each record's turn-on
  offset a random effect (what :mod:`~tak_thermo_ros.core.fit.pool` and a fleet's prior fit through);
- :mod:`~tak_thermo_ros.core.fit.handheld.plateau`: the plateau table of a table run (the
  paper's +/- quantities);
- :mod:`~tak_thermo_ros.core.fit.handheld.held`: what a record cannot determine, held and said;
- :mod:`~tak_thermo_ros.core.fit.handheld.fit`: :func:`fit_handheld` itself and its result.

The names the modules share among themselves (:class:`~tak_thermo_ros.core.fit.handheld.system.System`,
:class:`~tak_thermo_ros.core.fit.handheld.rests.Rests`, ...) are imported from their module, not from here.
"""

from tak_thermo_ros.core.fit.handheld.accel import GAUGE
from tak_thermo_ros.core.fit.handheld.fit import HandheldFit, fit_handheld, gauge_rotation, sensitivity
from tak_thermo_ros.core.fit.handheld.held import SPAN_PER_ORDER_C, orders_for_span
from tak_thermo_ros.core.fit.handheld.plateau import PlateauRow
from tak_thermo_ros.core.fit.handheld.pooled import TurnOnFit
from tak_thermo_ros.core.fit.handheld.settings import HandheldSettings

__all__ = ['GAUGE', 'SPAN_PER_ORDER_C', 'HandheldFit', 'HandheldSettings', 'PlateauRow', 'TurnOnFit', 'fit_handheld',
           'gauge_rotation', 'orders_for_span', 'sensitivity']
