"""The options ``tak_calib``'s commands share, and the bounds of every numeric option.

The bounds are checked where the command line is parsed.

Each function here is an ``argparse`` ``type=``: it turns the text into a number or raises
``argparse.ArgumentTypeError``, so that argparse prints its own one line
``tak_calib <command>: error: argument --gravity: ...`` and exits with status 2. Every bound
follows from the physics or from what the code downstream can represent:

- every number must be finite (``nan``, ``inf`` are refused everywhere);
- local gravity lies within :data:`GRAVITY_MIN` .. :data:`GRAVITY_MAX` m/s^2 (every place on the
  Earth's surface, from high mountains at the equator, about 9.76, to the poles, about 9.83,
  with a margin);
- a temperature code lies strictly within +-:data:`~tak_thermo_ros.core.records.record.TEMP_CODE_LIMIT`
  (beyond any 24-bit sensor code), a reference component within
  +-:data:`~tak_thermo_ros.core.records.record.REFERENCE_LIMIT` m/s^2;
- times (``--settle-time``) are finite and not negative; resolutions are positive; a nominal
  scale lies within 0 .. :data:`MAX_NOMINAL_SCALE` counts per m/s^2;
- polynomial orders lie within 0 .. :data:`MAX_ORDER`; cross-validation needs 2 folds or more;
- a random seed is a whole number 0 .. 2**63 - 1;
- effect names (``--effects``, ``--candidates``) resolve to an effect: a library name, a recorded
  signal ``aux:TOPIC[:FIELD]``, or an importable ``module:Class``.

So every option is checked before any input is read or any output opened (``fit-fleet``'s too,
before its cluster starts).
"""

from __future__ import annotations

import argparse
import math
from typing import Any, Callable

from tak_thermo_ros.core.records.record import REFERENCE_LIMIT, TEMP_CODE_LIMIT
from tak_thermo_ros.core.values import STANDARD_GRAVITY

GRAVITY_MIN = 9.7
"""Lowest accepted local gravity, m/s^2."""
GRAVITY_MAX = 9.9
"""Highest accepted local gravity, m/s^2."""
MAX_ORDER = 8
"""Highest polynomial order of ``F_s`` and ``F_c`` (higher orders only fit noise)."""
MAX_FOLDS = 100
"""Most cross-validation folds ``diagnose`` accepts."""
MAX_SEED = 2 ** 63 - 1
"""Largest random seed."""
MAX_NOMINAL_SCALE = 1e7
"""Largest nominal scale, counts per m/s^2 (a 24-bit channel over +-2 g has 4e5)."""
MIN_SAMPLE_BUDGET = 1000
"""Fewest samples ``--effect-samples`` / ``--max-samples`` accept.

Fewer cannot show an effect's shape against the noise.
"""
MAX_SAMPLE_BUDGET = 10 ** 9
"""Most samples those options accept."""
MAX_INSTANCE = 255
"""Largest sensor instance of a flight log (PX4's ``multi_id`` and ArduPilot's ``I`` are one byte)."""


def _float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        msg = f'{text!r} is not a number'
        raise argparse.ArgumentTypeError(msg) from None
    if not math.isfinite(value):
        msg = f'{text!r} is not a finite number'
        raise argparse.ArgumentTypeError(msg)
    return value


def float_within(low: float, high: float, unit: str = '', *, low_open: bool = False,
                 high_open: bool = False) -> Callable[[str], float]:
    """A finite number within ``[low, high]``; ``low_open``, ``high_open`` leave a bound out."""
    unit_text = f' {unit}' if unit else ''

    def parse(text: str) -> float:
        value = _float(text)
        inside = (value > low if low_open else value >= low) and (value < high if high_open else value <= high)
        if not inside:
            if math.isinf(high):
                bound = f'> {low:g}' if low_open else f'>= {low:g}'
                msg = f'{text} is out of range: must be {bound}{unit_text}'
            else:
                interval = f'{"(" if low_open else "["}{low:g}, {high:g}{")" if high_open else "]"}'
                msg = f'{text} is out of range: must lie within {interval}{unit_text}'
            raise argparse.ArgumentTypeError(msg)
        return value

    parse.__name__ = 'number'
    return parse


def int_within(low: int, high: int) -> Callable[[str], int]:
    """A whole number within ``[low, high]``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            msg = f'{text!r} is not a whole number'
            raise argparse.ArgumentTypeError(msg) from None
        if not low <= value <= high:
            msg = f'{text} is out of range: must lie within {low}..{high}'
            raise argparse.ArgumentTypeError(msg)
        return value

    parse.__name__ = 'whole number'
    return parse


def effect_specs(text: str) -> str:
    """``--effects NAME[,NAME...]``: the text as given, once every name resolves to an effect class.

    (:func:`~tak_thermo_ros.core.effects.resolve_effect`: a library name, ``aux:TOPIC[:FIELD]``,
    ``module:Class``); the text stays a text, so that ``fit-fleet`` hands it on as given.
    """
    from tak_thermo_ros.core.effects import resolve_effect
    from tak_thermo_ros.errors import TakError
    for spec in (part.strip() for part in text.split(',')):
        if spec:
            try:
                resolve_effect(spec)
            except TakError as err:
                raise argparse.ArgumentTypeError(str(err)) from None
    return text


HELD_SPREAD_UNITS = {'offset': {'accel': ('mg', 9.80665e-3), 'gyro': ('deg/h', math.pi / 180.0 / 3600.0)},
                     'offset_drift': {'accel': ('mg/C', 9.80665e-3), 'gyro': ('deg/h/C', math.pi / 180.0 / 3600.0)},
                     'scale': {'accel': ('%', 1e-2), 'gyro': ('%', 1e-2)},
                     'scale_drift': {'accel': ('%/C', 1e-2), 'gyro': ('%/C', 1e-2)},
                     'coupling': {'accel': ('mrad', 1e-3), 'gyro': ('mrad', 1e-3)}}
"""``fit --held-spread``'s names (``accel_scale``, ``gyro_offset_drift``, ...) and the units a person gives them in."""


def held_spread(text: str) -> tuple[str, float]:
    """``--held-spread NAME=VALUE``: a held term's default spread, in SI.

    ``VALUE`` in the unit :data:`HELD_SPREAD_UNITS` gives the name (mg, deg/h, %, mrad): a field of
    :class:`~tak_thermo_ros.core.fit.link_uncertainty.HeldSpreads`.
    """
    name, _, value = text.partition('=')
    sensor, _, kind = name.strip().partition('_')
    units = HELD_SPREAD_UNITS.get(kind, {}).get(sensor)
    if units is None:
        msg = f'{text!r}: expected NAME=VALUE, NAME accel_ or gyro_ and {", ".join(HELD_SPREAD_UNITS)}'
        raise argparse.ArgumentTypeError(msg)
    number = float_within(0.0, math.inf, units[0], low_open=True)(value.strip())
    return f'{sensor}_{kind}', number * units[1]


def candidates(text: str) -> str:
    """``diagnose --candidates``: as :func:`effect_specs`, ``library`` standing for every library effect."""
    effect_specs(','.join(part for part in text.split(',') if part.strip() != 'library'))
    return text


effect_specs.__name__ = candidates.__name__ = 'effect names'


class OneOrThree(argparse.Action):
    """An option of one value or three (x y z): any other count is refused where it is parsed."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        """Store the values, or refuse a count other than one or three."""
        if len(values) not in (1, 3):
            msg = f'takes one value or three (x y z), got {len(values)}'
            raise argparse.ArgumentError(self, msg)
        setattr(namespace, self.dest, values)


MAX_WORKERS = 256
"""Most worker processes of ``fit-fleet``'s local cluster."""
gravity = float_within(GRAVITY_MIN, GRAVITY_MAX, 'm/s^2 (local gravity on the Earth\'s surface)')
"""``--gravity``."""
seconds_not_negative = float_within(0.0, math.inf, 's')
"""``--settle-time``."""
temp_code = float_within(-TEMP_CODE_LIMIT, TEMP_CODE_LIMIT, '(temperature-sensor code)', low_open=True,
                         high_open=True)
"""``--temp-code-ref``."""
positive = float_within(0.0, math.inf, low_open=True)
"""Resolutions."""
nominal_scale = float_within(0.0, MAX_NOMINAL_SCALE, 'counts per m/s^2', low_open=True)
"""``--nominal-scale``."""
specific_force = float_within(-REFERENCE_LIMIT, REFERENCE_LIMIT, 'm/s^2', low_open=True, high_open=True)
"""``--reference`` components."""
polynomial_order = int_within(0, MAX_ORDER)
"""``--bias-order``, ``--scale-order``."""
folds = int_within(2, MAX_FOLDS)
"""``--folds``."""
seed = int_within(0, MAX_SEED)
"""``simulate --seed``."""
sample_budget = int_within(MIN_SAMPLE_BUDGET, MAX_SAMPLE_BUDGET)
"""``fit --effect-samples``, ``diagnose --max-samples``."""
latitude = float_within(-90.0, 90.0, "degrees")
"""``--latitude`` (a static driver bag's Earth rate)."""


# The options several commands share: each command's module adds its own and calls these.

def add_topic_options(parser: argparse.ArgumentParser, *, imu: bool = False) -> None:
    """The bag's topics, ``--no-progress``, ``--force``, ``--verbose``, ``--debug`` (every command reading a bag)."""
    group = parser.add_argument_group('topics (the input kind is taken from the bag: counts topic or driver Imu)')
    group.add_argument('--counts-topic', default='/tak/counts', help='channel codes (Vector3Stamped)')
    group.add_argument('--raw-imu-topic', default='/imu/data_raw', help="a driver's Imu (default /imu/data_raw)")
    group.add_argument('--temp-topic', help='temperature (Temperature): codes /tak/temp_code with counts, '
                                            'degrees C /imu/temperature with a driver Imu')
    group.add_argument('--reference-topic', default='/tak/reference', help='true specific force (Vector3Stamped)')
    group.add_argument('--mag-topic', default='/imu/mag', help="a driver's magnetometer (MagneticField, tesla)")
    group.add_argument('--reference-field-topic', default='/tak/reference_field',
                       help='true magnetic field along the sensor axes, tesla (Vector3Stamped; a coil)')
    group.add_argument('--reference-rate-topic', default='/tak/reference_rate',
                       help='true angular rate, rad/s (Vector3Stamped; driver bags)')
    group.add_argument('--instance', type=int_within(0, MAX_INSTANCE), default=0, metavar='N',
                       help='a flight log (PX4 ULog, ArduPilot .bin) in place of the bag: the sensor instance to read '
                            '(default 0)')
    if imu:
        group.add_argument('--imu-topic', help='corrected output (Imu): default /tak/imu/data_raw with counts, '
                                               '/imu/data_compensated with a driver Imu')
    parser.add_argument('--no-progress', action='store_true', help='no progress bar even on a terminal')
    parser.add_argument('--force', action='store_true',
                        help='replace an existing output (a regular file, a bag or a report directory; '
                             'nothing else is ever replaced)')
    parser.add_argument('-v', '--verbose', action='store_true', default=argparse.SUPPRESS,
                        help='print the detail too (the physics behind a verdict, ...); the JSON holds it all')
    parser.add_argument('--debug', action='store_true', default=argparse.SUPPRESS,
                        help='show the traceback of an error')


def add_static_options(parser: argparse.ArgumentParser) -> None:
    """``--gravity`` and ``--latitude``: the reference of a driver bag without reference topics."""
    group = parser.add_argument_group('driver bags without reference topics (a static run)')
    group.add_argument('--gravity', type=gravity, default=None,
                       help='local gravity, m/s^2: the magnitude of the estimated specific-force reference '
                            f'(default: from --latitude on the WGS-84 ellipsoid, else {STANDARD_GRAVITY:g})')
    group.add_argument('--latitude', type=latitude, metavar='DEG',
                       help="adds the Earth rate's vertical component (Omega_E sin(latitude), along the "
                            'measured up direction) to the rate reference, and gives local gravity where '
                            '--gravity is not given; default zero')


def resolve_gravity(args: argparse.Namespace) -> None:
    """``--gravity`` as given, else the normal gravity at ``--latitude``, else standard gravity (in place)."""
    from tak_thermo_ros.core.values import normal_gravity
    if 'gravity' in vars(args) and args.gravity is None:
        latitude_deg = getattr(args, 'latitude', None)
        args.gravity = normal_gravity(latitude_deg) if latitude_deg is not None else STANDARD_GRAVITY


def add_out_of_range(parser: argparse.ArgumentParser) -> None:
    """``--out-of-range``: what a correction does outside the calibrated temperature range."""
    from tak_thermo_ros.core.link.correction import OutOfRange
    parser.add_argument('--out-of-range', choices=[p.value for p in OutOfRange], default=OutOfRange.CLAMP.value,
                        help='temperature codes outside the calibrated range: clamp to the edge (default) '
                             'or extrapolate the polynomials; either way the count is reported')
