"""What the calibration watch says: what moved, its verdict, its figures and its log lines.

:class:`Finding` is what moved on a channel once a test fired; :class:`WatchWords`, a base of
:class:`~tak_thermo_ros.core.link.watch.CalibrationWatch`, turns the watch's state into words (the
node's status values, ``tak_calib validate``'s lines) and judges nothing itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from tak_thermo_ros.core.link.learning import Learner
from tak_thermo_ros.core.link.rest_noise import CHANNELS, JudgedRest
from tak_thermo_ros.core.link.rests import RestFinder
from tak_thermo_ros.core.values import DEG_PER_H, MG


@dataclass
class Finding:
    """What moved on one channel, once its test fired.

    :param channel: one of :data:`CHANNELS`.
    :param kind: ``offset`` (turn-on beyond the repeatability, or a step) or ``slope``.
    :param size: the change, SI (rad/s, m/s^2; per degree C for a slope).
    :param z: its size over its standard deviation.
    :param rest: the rest at which the test fired.
    :param axis: the axis it is named on (``x``, ``y``, ``z``).
    :param turn_on: whether it is the first rest's turn-on offset.
    :param why: what the test judged it against, in words (the log line's).
    """

    channel: str
    kind: str
    size: float
    z: float
    rest: int
    axis: str
    turn_on: bool = False
    why: str = ''

    @property
    def sigma(self) -> float:
        """The standard deviation the change was judged against (its size over its z), SI."""
        return abs(self.size / self.z) if self.z else math.inf

    def judged(self) -> str:
        """``gyro x offset +812 deg/h: 12.3 sigma at rest 1 (1 sigma 66 deg/h: turn-on offset beyond ...)``."""
        if self.channel == 'accel':
            one = f'{self.sigma * MG:.3g} mg' + (' per C' if self.kind == 'slope' else '')
        else:
            one = f'{self.sigma * DEG_PER_H:.3g} deg/h' + ('/C' if self.kind == 'slope' else '')
        return f'{self.text()}: {abs(self.z):.1f} sigma at rest {self.rest} (1 sigma {one}; {self.why})'

    def text(self) -> str:
        """``gyro x offset +812 deg/h``, ``gyro y slope +2.1 deg/h/C``, ``accel z 3.2 mg``."""
        if self.channel == 'accel':
            return f'accel {self.axis} {self.size * MG:+.3g} mg' + (' per C' if self.kind == 'slope' else '')
        unit = 'deg/h/C' if self.kind == 'slope' else 'deg/h'
        return f'{self.channel} {self.kind} {self.size * DEG_PER_H:+.3g} {unit}'


@dataclass
class ChannelState:
    """One channel's figures at the latest rest (for the diagnostics)."""

    residual: float = math.nan
    z: float = 0.0


class WatchWords:
    """The words of a watch's state: verdict, figures, what to do (see the module).

    A base of :class:`~tak_thermo_ros.core.link.watch.CalibrationWatch`; what it reads is the
    watch's (set in its ``__init__``), annotated below.
    """

    findings: dict[str, Finding]
    learner: Learner | None
    finder: RestFinder
    first: JudgedRest | None
    judged: list[JudgedRest]
    channels: dict[str, ChannelState]
    rests_judged: int
    rest_hours: float
    false_alarms_per_hour: float
    undetermined: list[tuple[int, float, float]]
    turn_on_enabled: bool
    turn_on_lines: list[str]
    repeatability_source: tuple[str, ...]
    _turn_on_sd: tuple[Any, Any]
    """``(accel, gyro)``: the turn-on repeatability each is judged against (a ``Repeatability``), or ``None``."""

    def first_rest_unjudged(self) -> str:
        """Why a run's first rest is not judged (no turn-on repeatability for the gyroscope), or ``''``."""
        if self._turn_on_sd[1] is not None:
            return ''
        return ('unjudged: the calibration holds no gyro turn-on repeatability; later rests are judged against '
                'the first (give gyro_turn_on_repeatability, or learn over 5 runs)')

    def first_rest_words(self) -> str:
        """What the first rest is judged against (the status's ``first_rest``)."""
        unjudged = self.first_rest_unjudged()
        if unjudged:
            return unjudged
        gyro = self._turn_on_sd[1].repeatability  # type: ignore[union-attr]
        return (f'judged against the gyro turn-on repeatability {" ".join(f"{v * DEG_PER_H:.3g}" for v in gyro)} '
                f'deg/h x y z (from {self.repeatability_source[1]})')

    def what_to_do(self) -> str:
        """One line: refit, or what learning has done about what the watch found (``''``: nothing found)."""
        if not self.findings:
            return ''
        refit = 'refit from the records the unit made since (tak_calib fit REC... -o NEW.yaml)'
        learner = self.learner
        if learner is None:
            return f'{refit}, or learn it (learn: true); docs/watch.md'
        words = []
        for finding in self.findings.values():
            if finding.channel == 'accel':
                words.append(f'accel (not learned): {refit}')
                continue
            axis = 'xyz'.index(finding.channel[-1])
            since = learner.accepted_since[axis]
            words.append(f'learning takes {finding.channel}: its rests follow the learned curve from rest {since} on'
                         if since is not None else
                         f'learning is taking {finding.channel} ({learner.rejected} rests left out so far)')
        return '; '.join(words)

    @property
    def stale(self) -> bool:
        """Whether a test fired in this run."""
        return bool(self.findings)

    def verdict(self) -> str:
        """One line: ``calibration stale: ...`` or ``calibration holds ...`` (or no rest yet)."""
        if self.findings:
            moved = ', '.join(f.text() for f in self.findings.values())
            return f'calibration stale: {moved} (at rest {min(f.rest for f in self.findings.values())})'
        if not self.rests_judged:
            return 'calibration holds as far as known: no rest yet'
        return (f'calibration holds at {self.rests_judged} rests ({self.rest_hours * 60.0:.1f} min; '
                f'false alarms at most {self.false_alarms_per_hour:g} per hour of rests)')

    def values(self) -> list[tuple[str, str]]:
        """The figures as ``(key, value)`` pairs: per channel the residual at the last rest and its size in sigma."""
        values = [('rests', str(self.rests_judged)), ('rest_minutes', f'{self.rest_hours * 60.0:.2f}'),
                  ('false_alarms_per_hour', f'{self.false_alarms_per_hour:g}'),
                  ('windows', str(self.finder.windows)), ('still_windows', str(self.finder.still_windows))]
        last = self.judged[-1] if self.judged else self.first
        if last is not None:
            values.append(('since_last_rest_s', f'{max(0, self.finder.start_ns - last.rest.end_ns) * 1e-9:.1f}'))
            values.append(('last_rest_temperature', f'{last.rest.temperature:.4g}'))
        for channel, name in enumerate(CHANNELS):
            state = self.channels[name]
            key = name.replace(' ', '_')
            if channel < 3:
                values.append((f'{key}.bias_deg_h', f'{state.residual * DEG_PER_H:.4g}'))
            else:
                values.append(('accel.norm_error_mg', f'{state.residual * MG:.4g}'))
            values.append((f'{key}.sigma', f'{state.z:.3g}'))
        values.append(('accel.undetermined_rests', str(len(self.undetermined))))
        values.append(('first_rest', self.first_rest_words()))
        for finding in self.findings.values():
            values.append((f'stale.{finding.channel.replace(" ", "_")}', finding.judged()))
        if self.findings:
            values.append(('stale.what_to_do', self.what_to_do()))
        if self.learner is not None:  # learning takes the turn-on offset itself, whatever turn_on says
            offset = self.learner.adjustment()[0][3:]
            values.append(('turn_on', 'taken by learning: gyro x y z '
                                      f'{" ".join(f"{v * DEG_PER_H:+.4g}" for v in offset)} deg/h in force'
                           if self.learner.rests else 'learning takes it at the first rest'))
        elif self.turn_on_enabled:
            values.append(('turn_on', '; '.join(self.turn_on_lines) or 'waiting for the first rest'))
        if self.learner is not None:
            values += self.learner.values()
        return values

    def lines(self) -> list[str]:
        """What ``tak_calib validate`` prints: the verdict, what moved, the figures at the last rest (short lines)."""
        out = [self.verdict()]
        for finding in self.findings.values():
            out.append(f'  {finding.judged()}')
        if self.findings:
            out.append(f'  what to do: {self.what_to_do()}')
        unjudged = self.first_rest_unjudged()
        if unjudged and self.rests_judged:
            out.append(f'  rest 1 {unjudged}')
        if self.undetermined:
            _, uncertainty, noise = max(self.undetermined, key=lambda item: item[1] / item[2])
            out.append(f'  |f| not judged at {len(self.undetermined)} rests: the file leaves it undetermined there '
                       f'(+-{uncertainty * MG:.2g} mg, noise {noise * MG:.2g} mg)')
        last = self.judged[-1] if self.judged else self.first
        if last is not None:
            bias = ' '.join(f'{self.channels[n].residual * DEG_PER_H:+.3g}' for n in CHANNELS[:3])
            sigma = ' '.join(f'{self.channels[n].z:+.2g}' for n in CHANNELS[:3])
            rest = last.rest
            out.append(f'  last rest ({rest.index}: {rest.duration_s:.0f} s at {rest.temperature:.3g} C): '
                       f'gyro bias x y z {bias} deg/h')
            out.append(f'  last rest, in sigma of its noise: gyro x y z {sigma}; |f| error '
                       f'{self.channels["accel"].residual * MG:+.3g} mg ({self.channels["accel"].z:+.2g} sigma)')
        out.extend(f'  {line}' for line in self.turn_on_lines)
        return out
