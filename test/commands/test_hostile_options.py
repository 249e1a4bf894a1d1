# Copyright 2026 valve_sim developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
Options, sizes and outputs bounded; what goes on the wire finite and physical.

- every meaningless number of every command is a usage error naming the range;
- a study that cannot fit (samples, workers) is refused before anything is allocated,
  naming the limit and the memory it would need;
- outputs: --plot DIR writes inside DIR, a planted symbolic link at a name the user did
  not give is replaced and never followed, a full disk leaves the measures file valid;
- a sensor's readings are finite and within its range whatever its settings, and
  analyse --json writes null with a reason, never NaN or Infinity.
"""

import argparse
import json
import math
from pathlib import Path
import subprocess
import sys

from hostile_inputs import bag_with_inf_pressure
import numpy as np
import pytest
from valve_sim.commands.cli import main
from valve_sim.core.errors import ParameterError


pytestmark = pytest.mark.timeout(300)

REPO = Path(__file__).resolve().parents[2]
EVERY_BAD_NUMBER = ('nan', 'inf', '-inf', '1e300', '-1')
CALIBRATE = ['calibrate', '--target-measures', 'x.json', '--fit', 'd_c', '--out', 'o']
OPTIMISE = ['optimise', '--design', 'd_c=±5%', '--minimise', 'P_1_percent', '--tolerance',
            'd_c=±5um', '--out', 'o']
OPTIONS = [  # (command and its other arguments, option, values that mean nothing)
    (['analyse', 'bags/rig_step.mcap'], '--step-threshold', ('-1', 'nan', '2', '0')),
    (['analyse', 'bags/rig_step.mcap'], '--ambient-pressure', ('nan', '-1', 'inf', '1e300')),
    (['analyse', 'bags/rig_step.mcap'], '--step-time', ('nan', '1e300', '-1')),
    (['simulate'], '--step-time', EVERY_BAD_NUMBER),
    (['simulate'], '--ramp-time', EVERY_BAD_NUMBER),
    (['simulate'], '--end-time', EVERY_BAD_NUMBER),
    (['simulate'], '--record-interval', EVERY_BAD_NUMBER + ('0',)),
    (['simulate'], '--step-size', EVERY_BAD_NUMBER + ('0',)),
    (['simulate', '--mcap', 'x.mcap', '--rig-topics', 'p,q'], '--pressure-noise',
     EVERY_BAD_NUMBER),
    (['simulate'], '--seed', ('-1', 'nan', '1.5')),
    (['characteristic'], '--ramp-time', EVERY_BAD_NUMBER),
    (['characteristic'], '--hold-time', EVERY_BAD_NUMBER),
    (['characteristic'], '--record-interval', EVERY_BAD_NUMBER),
    (CALIBRATE, '--starts', ('0', '-1', '1000000000', 'nan')),
    (CALIBRATE, '--spread', EVERY_BAD_NUMBER),
    (CALIBRATE, '--tolerance', EVERY_BAD_NUMBER + ('0',)),
    (['tolerance', '--vary', 'd_c=±2%', '--out', 'o'], '--samples', ('0', '-5', 'nan', '1e9')),
    (['tolerance', '--vary', 'd_c=±2%', '--out', 'o'], '--workers', ('0', '-1', 'nan')),
    (['tolerance', '--vary', 'd_c=±2%', '--out', 'o'], '--batch-size', ('0', '-1', 'nan')),
    (['simulate'], '--initial-flow', ('nan', 'inf', '-1', '1e300', '11')),
    (['simulate', '--mcap', 'x.mcap', '--rig-topics', 'p,q'], '--flow-interval',
     EVERY_BAD_NUMBER + ('0',)),
    (CALIBRATE, '--bounds', ('d_c=nan:1', 'd_c=-inf:1', 'd_c=1:inf', 'd_c=2:1')),
    (CALIBRATE, '--relieves', ('d_c=nan', 'd_c=-100', 'd_c=1e300', 'd_c=inf')),
    (CALIBRATE, '--main-spring-rate', ('nan:1', '0:1', '1:inf', '2:1')),
    (CALIBRATE, '--pilot-flow-at', ('nan', '1e300', '-1')),
    (OPTIMISE, '--samples', ('0', '-1', 'nan', '1e300', '2000000')),
    (OPTIMISE, '--confirm-samples', ('-1', 'nan', '2000000')),
    (OPTIMISE, '--population', ('1', '0', 'nan', '100000')),
    (OPTIMISE, '--generations', ('0', '-1', 'inf', '100000')),
    (OPTIMISE, '--min-decay-rate', ('nan', '-1', 'inf', '1e300')),
    (OPTIMISE, '--defer-after', ('0', '-1', 'nan', 'inf', '1.5', '1e300')),
    (['tolerance', '--vary', 'd_c=±2%', '--out', 'o'], '--dashboard',
     ('127.0.0.1:99999', 'nohost', ':80', '127.0.0.1:-1')),
    (['demo'], '--foxglove', ('-1', '65536', 'nan')),
]


@pytest.mark.parametrize(
    'arguments, option, value',
    [(arguments, option, value) for arguments, option, values in OPTIONS for value in values],
)
def test_a_meaningless_number_is_a_usage_error_naming_the_range(
    capsys, monkeypatch, arguments, option, value
):
    monkeypatch.chdir(REPO)
    with pytest.raises(SystemExit) as exit_code:
        main([*arguments, f'{option}={value}'])
    error = capsys.readouterr().err
    assert exit_code.value.code == 2 and option in error, error
    assert 'must be' in error or 'not a' in error or 'not an' in error, error


def test_every_numeric_option_is_bounded_and_its_help_gives_the_bounds():
    """
    No option of any command parses a bare int or float; --help and the docs give the bounds.

    docs/valve_node.md states each bound. The class, not the examples: a numeric option
    added later without a bounded type (options.number, flow_value, pressure_value)
    fails here.
    """
    from valve_sim.commands.cli import build_parser, SUBCOMMANDS

    docs = (REPO / 'docs' / 'valve_node.md').read_text()
    for command in SUBCOMMANDS:
        parser = build_parser([command])
        sub = parser._subparsers._group_actions[0].choices[command]
        row = next((line for line in docs.splitlines() if line.startswith(f'| `{command}` |')), '')
        nested = [choice for action in sub._actions if action.choices and isinstance(
            action, argparse._SubParsersAction) for choice in action.choices.values()]
        numeric = []
        for each in [sub, *nested]:  # a command's actions (scenario run, check) too
            text = ' '.join(each.format_help().split())
            for action in each._actions:
                assert action.type not in (int, float), (command, action.option_strings)
                bounds = getattr(action.type, 'bounds', None)
                if bounds:
                    assert ' '.join(bounds.split()) in text, (command, action.option_strings)
                    assert f'`{action.option_strings[-1]}` {bounds}' in row, (command, bounds)
            numeric += [a for a in each._actions if getattr(a.type, 'bounds', None)]
        assert numeric or command in ('repair',), command


def test_a_step_time_outside_the_recording_is_refused(capsys):
    code = main(['analyse', str(REPO / 'bags/rig_step.mcap'), '--topic-supply-pressure',
                 '/rig/inlet_pressure', '--clock', 'receive', '--step-time', '5'])
    error = capsys.readouterr().err
    assert code == 1 and 'outside the recording' in error and error.count('\n') == 1, error


@pytest.mark.parametrize(
    'arguments, limit',
    [
        (['tolerance', '--vary', 'd_c=±2%', '--samples', '1000000000'], 'runs'),
        (['tolerance', '--vary', 'd_c=±2%', '--samples', '1000001'], 'runs'),
        (['sensitivity', '--samples', '1073741824'], 'runs'),
        (['tolerance', '--vary', 'd_c=±2%', '--samples', '4', '--workers', '100000'], 'workers'),
        ([*OPTIMISE[:-2], '--samples', '524288'], 'valves'),
        ([*OPTIMISE[:-2], '--samples', '4', '--confirm-samples', '524288'], 'valves'),
        ([*OPTIMISE[:-2], '--samples', '4', '--population', '10000', '--generations', '11'],
         'candidates'),
    ],
)
def test_a_study_that_cannot_fit_is_refused_naming_the_limit_and_the_memory(
    tmp_path, capsys, arguments, limit
):
    pytest.importorskip('distributed')
    pytest.importorskip({'sensitivity': 'SALib', 'optimise': 'pymoo'}.get(arguments[0], 'dask'))
    code = main([*arguments, '--out', str(tmp_path / 'out')])
    error = capsys.readouterr().err
    assert code == 1 and error.count('\n') == 1, error
    assert 'the limit' in error and 'memory' in error and 'B ' in error and limit in error, error
    assert not (tmp_path / 'out' / 'results.jsonl').exists(), 'refused before anything ran'


def test_plot_into_an_existing_folder_writes_inside_it(tmp_path, capsys):
    folder = tmp_path / 'out'
    folder.mkdir()
    run = ['simulate', '--end-time', '0.4', '--step-time', '0.1', '--plot', str(folder)]
    assert main(run) == 0
    assert (folder / 'figure5.png').stat().st_size > 0
    assert not (tmp_path / 'out.png').exists(), 'nothing beside the folder'
    assert main(['analyse', str(REPO / 'bags/reference_step.mcap'), '--plot', str(folder)]) == 0
    assert sorted(p.name for p in folder.iterdir()) == ['figure5.png']
    capsys.readouterr()


def test_repair_never_follows_a_planted_link_at_its_default_output(tmp_path, capsys):
    """BAG.repaired.mcap planted as a link to another file: replaced, the file untouched."""
    bag = tmp_path / 'bag.mcap'
    bag.write_bytes((REPO / 'bags/reference_step.mcap').read_bytes()[:600_000])
    victim = tmp_path / 'victim.txt'
    victim.write_text('precious')
    (tmp_path / 'bag.repaired.mcap').symlink_to(victim)
    assert main(['repair', str(bag)]) == 0
    assert victim.read_text() == 'precious'
    assert not (tmp_path / 'bag.repaired.mcap').is_symlink()
    named = tmp_path / 'named.mcap'
    named.symlink_to(tmp_path / 'through.mcap')
    assert main(['repair', str(bag), '-o', str(named)]) == 0
    assert named.is_symlink() and (tmp_path / 'through.mcap').stat().st_size > 0, 'as named'
    assert not [p for p in tmp_path.iterdir() if p.name.endswith('.part')], 'no leftovers'
    capsys.readouterr()


def test_a_results_file_that_is_a_link_is_refused(tmp_path):
    from valve_sim.analysis.studies.backend import SerialBackend
    from valve_sim.analysis.studies.runner import run_cases
    from valve_sim.core.errors import StudyError

    victim = tmp_path / 'victim.jsonl'
    victim.write_text('precious\n')
    link = tmp_path / 'results.jsonl'
    link.symlink_to(victim)
    for resume in (False, True):
        with pytest.raises(StudyError, match='symbolic link'):
            run_cases([], link, SerialBackend(), resume=resume)
    assert victim.read_text() == 'precious\n'


FULL_DISK = """
import json, resource, signal, sys
from valve_sim.analysis.steps.step_analysis import MeasuresFile
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails, as on a full disk
measures = MeasuresFile(sys.argv[1], 'bag.mcap')
record = {'t_step': 1.0, 'direction': 1, 'flow_before': 1e-4, 'note': 'x' * 4000}
for _ in range(3):
    measures.append(record)
resource.setrlimit(resource.RLIMIT_FSIZE, (16000, 16000))
try:
    for _ in range(10):
        measures.append(record)
except OSError as error:
    print('failed:', error.strerror)
"""


def test_a_full_disk_during_a_measures_append_leaves_the_file_valid(tmp_path):
    """The disk fills (a file size limit) during an append: the file keeps every step before."""
    path = tmp_path / 'bag.measures.json'
    result = subprocess.run(
        [sys.executable, '-c', FULL_DISK, str(path)],
        capture_output=True, text=True, timeout=120, cwd=REPO,
    )
    assert 'failed:' in result.stdout, (result.stdout, result.stderr)
    document = json.loads(path.read_text())
    assert document['bag'] == 'bag.mcap' and len(document['steps']) == 3
    assert [p.name for p in tmp_path.iterdir()] == [path.name], 'no temporary file left'


# --- what goes on the wire --------------------------------------------------------------------


def test_a_resolution_that_breaks_the_arithmetic_is_refused(capsys):
    from valve_sim.core.sensors import check_sensor

    for value in (1e-320, 5e-324, 1e-10):
        with pytest.raises(ParameterError, match='at least'):
            check_sensor('sensor.supply_pressure.resolution', value)
    assert main(['simulate', '--set', 'sensor.supply_pressure.resolution=1e-320']) == 1
    assert 'resolution' in capsys.readouterr().err


def test_sensor_readings_are_finite_and_in_range_whatever_the_settings():
    """Fuzz: 2000 random settings within the specs, stuck or not: every reading in range."""
    from valve_sim.core.sensors import (
        checked_settings,
        default_settings,
        PRESSURE_NAMES,
        SENSOR_DOUBLE_SPECS,
        SensorStage,
    )

    rng = np.random.default_rng(25)
    topic = PRESSURE_NAMES[0]
    for trial in range(2000):
        settings = {}
        for name, spec in SENSOR_DOUBLE_SPECS.items():
            if name.startswith(f'sensor.{topic}.') and rng.random() < 0.6:
                low, high = spec.minimum, spec.maximum
                value = float(np.exp(rng.uniform(-30, np.log(high)))) if high > 0 else 0.0
                settings[name] = value if rng.random() < 0.9 else rng.choice([low, high])
        settings[f'sensor.{topic}.stuck'] = bool(rng.random() < 0.3)
        try:
            settings = checked_settings(default_settings(), settings)
        except ParameterError:
            continue  # a range_max not above range_min, a resolution too fine
        stage = SensorStage(settings)
        low = settings[f'sensor.{topic}.range_min']
        high = settings[f'sensor.{topic}.range_max'] or math.inf
        for step in range(5):
            pressures = rng.uniform(-1e6, 1e9, 4)
            reading = stage.read(step * 1_000_000, list(pressures))[0]
            assert math.isfinite(reading) and 0.0 <= low <= reading <= high, (settings, reading)


def test_a_stuck_sensor_saturates_at_its_range():
    from valve_sim.core.sensors import default_settings, SensorStage

    stage = SensorStage({
        **default_settings(),
        'sensor.supply_pressure.range_max': 1e7,
        'sensor.supply_pressure.stuck': True,
        'sensor.supply_pressure.stuck_at': 1e9,
    })
    assert stage.read(0, [7e6, 7e6, 7e6, 7e6])[0] == 1e7


def test_analyse_json_of_non_finite_samples_is_strict_json_with_reasons(tmp_path, capsys):
    """A bag whose supply pressure turns to inf: null measures with reasons, never Infinity."""
    path = tmp_path / 'inf.mcap'
    bag_with_inf_pressure(path)
    assert main(['analyse', str(path), '--json']) == 0
    out, err = capsys.readouterr()
    document = json.loads(out, parse_constant=lambda name: pytest.fail(f'{name} in the JSON'))
    assert 'not finite' in err
    step = document['steps'][0]
    assert all(step[name] is None or math.isfinite(step[name]) for name in ('P_o_percent',))
