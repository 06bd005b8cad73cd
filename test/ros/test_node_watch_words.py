"""What the real node (rclpy) says of its calibration watch (issue 39 item 5), and ``validate`` the same.

Learning refused in one line when the watch cannot run; a stale status that carries the log line's
size in sigma, what it was judged against and what to do; ``turn_on`` as learning applies it; a file
without a turn-on repeatability: its first rest unjudged, until a parameter (or learning's runs) gives one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from everyday_watch import HABITS, LATITUDE, everyday_runs, watch_unit
from node_helpers import Harness, NodeProcess, node_command, play_driver, run_to_exit, status_values
from tak_thermo_ros import cli
from tak_thermo_ros.core.link.learning import MIN_SPREAD_RUNS, LearnedState
from tak_thermo_ros.core.link.watch import WatchSettings
from tak_thermo_ros.core.values import DEG_PER_H
from tak_thermo_ros.formats.bag import write_driver_record
from tak_thermo_ros.formats.calibration_file import save_unit

UNIT = watch_unit()
SHORT = replace(HABITS, record_minutes=4.0)
WATCH = 'calibration watch'


def test_learn_without_a_noise_model_is_refused_in_one_line(tmp_path, ros_env):
    """learn:=true (and turn_on) with a calibration the watch cannot judge: exit 2, one line naming what is missing."""
    bare = tmp_path / 'bare.yaml'
    save_unit(bare, replace(UNIT, accel=replace(UNIT.accel, noise=None), gyro=replace(UNIT.gyro, noise=None)))
    result = run_to_exit(node_command('-p', f'calibration_file:={bare}', '-p', 'learn:=true', '-p',
                                      f'learned_file:={tmp_path / "learned.yaml"}'), ros_env)
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if 'learn' in line]
    assert len(lines) == 1 and 'learn: true needs the calibration watch, which cannot run' in lines[0]
    assert 'no noise model for the accel and the gyro' in lines[0]
    result = run_to_exit(node_command('-p', f'calibration_file:={bare}', '-p', 'turn_on:=first_rest'), ros_env)
    assert result.returncode == 2 and 'turn_on: first_rest needs the calibration watch' in result.stderr


def test_a_first_rest_unjudged_without_a_repeatability_judged_with_the_parameter(tmp_path, ros_env, capsys):
    """One chamber run's file (no turn_on): rest 1 unjudged, said; with the data sheet's repeatability, judged.

    The moved gyro x offset is stale at rest 1 then: the status carries the size in sigma, the
    repeatability it was judged against and what to do; ``validate`` prints the same lines.
    """
    record = everyday_runs(2, ('offset',), habits=SHORT)['offset'].record
    bag, params = tmp_path / 'moved.mcap', tmp_path / 'chamber.yaml'
    write_driver_record(bag, record)
    save_unit(params, replace(UNIT, accel=replace(UNIT.accel, turn_on=None), gyro=replace(UNIT.gyro, turn_on=None)))
    assert cli.main(['validate', str(bag), '--params', str(params), '--latitude', str(LATITUDE), '--no-progress']) == 0
    out = capsys.readouterr().out
    assert '  rest 1 unjudged: the calibration holds no gyro turn-on repeatability' in out
    repeatability = [v * DEG_PER_H for v in HABITS.turn_on('gyro')]
    given = f'gyro_turn_on_repeatability:=[{", ".join(f"{v:.1f}" for v in repeatability)}]'
    for extra, log in (((), 'unjudged.log'), (('-p', given), 'judged.log')):
        with NodeProcess(node_command('-p', f'calibration_file:={params}', '-p', 'qos:=reliable', '-p',
                                      f'latitude:={LATITUDE}', *extra), ros_env, tmp_path / log) as node, \
                Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
            ros.wait_matched()
            play_driver(ros, record)
            ros.wait(lambda: ros.latest_status(WATCH) is not None
                     and int(status_values(ros.latest_status(WATCH))['rests']) >= 3, 20.0, 'three rests judged')
            status = ros.latest_status(WATCH)
            values = status_values(status)
            assert node.stop() == 0
        if not extra:
            assert values['first_rest'].startswith('unjudged: the calibration holds no gyro turn-on repeatability')
            assert 'first rest unjudged' in node.log() and 'calibration watch: rest 1 unjudged' in node.log()
            assert 'gyro x offset' not in status.message  # a constant change: no rest judges it
            continue
        assert values['first_rest'].startswith('judged against the gyro turn-on repeatability 61.9 61.9 82.5 deg/h')
        assert values['first_rest'].endswith('(from gyro_turn_on_repeatability)')
        assert status.level == b'\x01' and status.message.startswith('calibration stale: gyro x offset +')
        judged = values['stale.gyro_x']
        assert judged.startswith('gyro x offset +') and ' sigma at rest 1 (1 sigma ' in judged
        assert 'turn-on offset beyond the repeatability 61.9 deg/h' in judged
        assert 'tak_calib fit' in values['stale.what_to_do'] and 'learn: true' in values['stale.what_to_do']
        logged = next(line for line in node.log().splitlines() if 'calibration stale at rest 1' in line)
        assert logged.split('(')[1].split(' sigma')[0] in judged  # the log's size in sigma


def test_turn_on_says_what_learning_applies_and_learning_keeps_the_runs_spread(tmp_path, ros_env):
    """With learning the status's turn_on is the offset learning applies; the learned file keeps the run's offset."""
    from tak_thermo_ros.formats.learned_file import load_learned
    record = everyday_runs(4, ('healthy',), habits=SHORT)['healthy'].record
    params, learned = tmp_path / 'unit.yaml', tmp_path / 'learned.yaml'
    save_unit(params, UNIT)
    with NodeProcess(node_command('-p', f'calibration_file:={params}', '-p', 'qos:=reliable', '-p',
                                  f'latitude:={LATITUDE}', '-p', 'turn_on:=first_rest', '-p', 'learn:=true', '-p',
                                  f'learned_file:={learned}'), ros_env, tmp_path / 'node.log') as node, \
            Harness(int(ros_env['ROS_DOMAIN_ID']), driver=True) as ros:
        ros.wait_matched()
        play_driver(ros, record)
        ros.wait(lambda: ros.latest_status(WATCH) is not None
                 and int(status_values(ros.latest_status(WATCH))['learn.rests']) >= 2, 20.0, 'learning')
        values = status_values(ros.latest_status(WATCH))
        assert node.stop() == 0
    taken = values['turn_on']
    assert taken.startswith('taken by learning: gyro x y z ')
    applied = [float(v) for v in values['learn.gyro_offset_deg_h'].split()]
    shown = [float(v) for v in taken.split('gyro x y z ')[1].split(' deg/h')[0].split()]
    assert all(abs(a - b) <= 1e-3 * max(abs(a), 1.0) for a, b in zip(applied, shown)), (applied, shown)
    state = load_learned(learned)
    assert state.turn_on_runs == 1 and state.turn_on_spread() is None  # one run: no spread yet


def test_the_spread_of_five_runs_turn_on_offsets_judges_the_first_rest():
    """From MIN_SPREAD_RUNS runs on, the learned file's turn-on offsets give the repeatability the first rest needs."""
    offsets = [(1e-4, -2e-4, 3e-4), (-1e-4, 2e-4, -3e-4), (2e-4, 0.0, 1e-4), (0.0, 1e-4, -1e-4), (-2e-4, -1e-4, 0.0)]
    state = LearnedState(turn_on_runs=MIN_SPREAD_RUNS - 1,
                         turn_on_sum=tuple(sum(o[a] for o in offsets[:-1]) for a in range(3)),
                         turn_on_squares=tuple(sum(o[a] ** 2 for o in offsets[:-1]) for a in range(3)))
    assert WatchSettings(learn=state).repeatabilities() == (None, None)
    state = replace(state, turn_on_runs=MIN_SPREAD_RUNS,
                    turn_on_sum=tuple(sum(o[a] for o in offsets) for a in range(3)),
                    turn_on_squares=tuple(sum(o[a] ** 2 for o in offsets) for a in range(3)))
    _, gyro = WatchSettings(learn=state).repeatabilities()
    assert np.allclose(gyro.repeatability, np.std(np.array(offsets), axis=0, ddof=1))
    assert '5 earlier runs' in gyro.source
    assert LearnedState.from_mapping(state.to_mapping(), 'learned') == state
    older = {k: v for k, v in state.to_mapping().items() if not k.startswith('turn_on')}
    assert LearnedState.from_mapping(older, 'learned').turn_on_runs == 0  # a learned file from before
