"""A record is opened once (formats/records.py): a command opens each record once and hands it down.

Counted per path through the whole command (``tak_calib fit``): the records opened
(:func:`~tak_thermo_ros.formats.records.open_record`, any caller), their format worked out from
their first bytes, a flight log read, a bag's kind and streams read from its index. Each is
once per record: in a pooled fit of a directory of everyday records, in a fit of one everyday
record (a pool of one, that takes the record the command opened), in a fit of a ULog and in a fit
of a counts bag. A counts bag without its reference is refused as before, in the bag's words (the
words read from its index once more: only then).
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from conftest import SHORT
from tak_thermo_ros import cli
from tak_thermo_ros.core.simulation.imu import simulate
from tak_thermo_ros.core.simulation.everyday import everyday_scenario, simulate_everyday_record
from tak_thermo_ros.core.simulation.powered import PoweredRun, simulate_powered
from tak_thermo_ros.formats import bag, records, ulog
from tak_thermo_ros.formats.bag import Topics, write_driver_record, write_record
from tak_thermo_ros.passes.fit import fit_bag
from tak_thermo_ros.passes.run import FitSettings, StreamOptions
from tak_thermo_ros.errors import BagError

MONTH = {'sample_rate_hz': 10.0, 'seed': 5, 'everyday': {'records': 3, 'record_minutes': 10.0}}
"""Three everyday records of about 10 minutes at 10 Hz."""
WARM_UP = PoweredRun(duration_s=600.0, accel_rate_hz=2.0, gyro_rate_hz=3.0, gyro_phase_s=0.13, board_tau_s=300.0,
                     self_heating_tau_s=30.0)
"""A short warm-up as a PX4 ULog, each sensor on its own stamps."""
CHAMBER = replace(SHORT, plateaus_celsius=(10.0, 30.0), plateau_hours=0.05, ramp_celsius_per_minute=20.0, seed=3)
"""A short counts run (the paper's channel codes) of two plateaus."""


class Counts:
    """Per path, how often each way into a record was taken."""

    def __init__(self) -> None:
        self.opened: Counter = Counter()
        self.formats: Counter = Counter()
        self.logs_read: Counter = Counter()
        self.kinds: Counter = Counter()
        self.streams: Counter = Counter()

    def every(self) -> dict[str, Counter]:
        """Each counter by its name."""
        return {'opened': self.opened, 'formats': self.formats, 'logs_read': self.logs_read, 'kinds': self.kinds,
                'streams': self.streams}


def _key(path) -> str:
    return str(Path(path).resolve())


@pytest.fixture
def counts(monkeypatch) -> Counts:
    """Every opening of a record, its format, its flight log and its bag index, counted by path."""
    found = Counts()

    def counting(counter: Counter, function):
        def counted(path, *args, **kwargs):
            counter[_key(path)] += 1
            return function(path, *args, **kwargs)
        return counted

    init = records.Record.__init__

    def opened(self, path, topics) -> None:
        found.opened[_key(path)] += 1
        init(self, path, topics)

    monkeypatch.setattr(records.Record, '__init__', opened)
    monkeypatch.setattr(records, 'flight_log_format', counting(found.formats, records.flight_log_format))
    monkeypatch.setattr(ulog, '_read', counting(found.logs_read, ulog._read))
    monkeypatch.setattr(bag, 'bag_input_kind', counting(found.kinds, bag.bag_input_kind))
    monkeypatch.setattr(bag, 'bag_streams', counting(found.streams, bag.bag_streams))
    return found


def _fit(capsys, *argv) -> str:
    status = cli.main(['fit', *map(str, argv), '--no-progress'])
    out = capsys.readouterr()
    assert status == 0, out.out + out.err
    return out.out


def _once_each(found: Counts, paths, *, read: tuple[str, ...]) -> None:
    """Each of ``paths`` opened once, and each way in named in ``read`` taken once; nothing else opened."""
    expected = Counter({_key(path): 1 for path in paths})
    for name, counter in found.every().items():
        if name == 'opened' or name in read:
            assert counter == expected, f'{name}: {dict(counter)}'
        else:
            assert not counter, f'{name}: {dict(counter)}'


@pytest.fixture(scope='module')
def month(tmp_path_factory) -> Path:
    """A directory of three everyday records (bags)."""
    root = tmp_path_factory.mktemp('records_open')
    scenario, habits = everyday_scenario(MONTH)
    for index in range(3):
        write_driver_record(root / f'rec{index:02d}', simulate_everyday_record(scenario, habits, index).record)
    return root


def test_a_pooled_fit_opens_each_record_once(month, counts, capsys, tmp_path):
    """``fit DIR``: each record of the pool opened once, its format and its bag index read once."""
    out = _fit(capsys, month, '-o', tmp_path / 'p.yaml')
    assert 'pool: 3 of 3 records' in out
    _once_each(counts, sorted(month.iterdir()), read=('formats', 'kinds', 'streams'))


def test_an_everyday_record_alone_is_a_pool_of_the_record_opened(month, counts, capsys, tmp_path):
    """``fit REC`` of an everyday record: its pass finds it everyday, and the pool of one takes the same record."""
    out = _fit(capsys, month / 'rec00', '-o', tmp_path / 'p.yaml')
    assert 'an everyday record' in out and 'pool: 1 of 1 record' in out
    _once_each(counts, [month / 'rec00'], read=('formats', 'kinds', 'streams'))


def test_a_ulog_fit_opens_and_reads_the_log_once(counts, capsys, tmp_path):
    """``fit LOG.ulg``: the log opened once, its format worked out once and the file read once by the reader."""
    from tak_thermo_ros.formats.ulog import driver_topics, write_ulog
    log = tmp_path / 'warm.ulg'
    write_ulog(log, driver_topics(simulate_powered(WARM_UP).record), info={'sys_name': 'PX4'})
    _fit(capsys, log, '-o', tmp_path / 'p.yaml')
    _once_each(counts, [log], read=('formats', 'logs_read'))


@pytest.fixture(scope='module')
def chamber():
    """A short counts run (channel codes, its reference recorded)."""
    return simulate(CHAMBER).record


def test_a_counts_fit_opens_the_bag_once(chamber, counts, capsys, tmp_path):
    """``fit BAG`` of a counts bag: opened once, its format, kind and index read once (the reference there)."""
    write_record(tmp_path / 'run', chamber)
    _fit(capsys, tmp_path / 'run', '-o', tmp_path / 'p.yaml')
    _once_each(counts, [tmp_path / 'run'], read=('formats', 'kinds', 'streams'))


@pytest.mark.parametrize(('topic', 'held'), [('/other/reference', '/other/reference, /tak/counts, /tak/temp_code'),
                                             (None, '/tak/counts, /tak/temp_code')])
def test_a_counts_bag_without_its_reference_is_refused_in_its_words(chamber, counts, capsys, tmp_path, topic, held):
    """A counts bag without its reference topic: the fit refuses it as the bag reader words it (the topics it holds).

    Opened once; its index read a second time only to word the refusal.
    """
    bag = tmp_path / 'run'
    if topic is None:
        chamber = replace(chamber, reference_stamp_ns=np.zeros(0, dtype=np.int64), reference=np.zeros((0, 3)))
    write_record(bag, chamber, topics=Topics(reference=topic or '/tak/reference'))
    words = f'{bag}: topic /tak/reference not found (topics in the bag: {held})'
    status = cli.main(['fit', str(bag), '-o', str(tmp_path / 'p.yaml'), '--no-progress'])
    out = capsys.readouterr()
    assert status != 0 and not (tmp_path / 'p.yaml').exists()
    assert out.err == f'tak_calib: error: {words}\n'
    assert counts.opened == Counter({_key(bag): 1})
    assert counts.streams == Counter({_key(bag): 2})
    with pytest.raises(BagError, match=f'^{re.escape(words)}$'):
        fit_bag(records.open_record(bag, topics=Topics()), FitSettings(effects={}),
                StreamOptions(topics=Topics(), progress=False))
