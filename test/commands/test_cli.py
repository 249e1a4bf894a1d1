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

"""The valve-sim command line: simulate and study, as a user runs them."""

import csv
import json
from pathlib import Path
import subprocess
import sys

from figure5 import outside_tolerance
import pytest
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.commands.cli import negative_values_joined, SUBCOMMANDS


TABLE2 = Path(__file__).resolve().parents[2] / 'config' / 'table2.yaml'


def valve_sim(*args, check=True):
    result = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', *args],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if check:
        assert result.returncode == 0, result.stderr
    return result


def test_reference_run_reproduces_figure5_within_tolerance():
    measures = json.loads(valve_sim('simulate', '--json').stdout)
    assert measures['reasons'] == {}
    assert outside_tolerance(measures) == {}


def test_simulate_writes_csv_and_plot(tmp_path):
    csv_path, png_path = tmp_path / 'run.csv', tmp_path / 'fig5.png'
    out = valve_sim(
        'simulate', '--end-time', '0.4', '--csv', str(csv_path), '--plot', str(png_path)
    ).stdout
    assert 'T_1_ms' in out and 'paper' in out
    with open(csv_path) as stream:
        rows = list(csv.reader(stream))
    assert rows[0][:3] == ['time_s', 'inlet_flow_m3_s', 'supply_pressure_Pa']
    assert len(rows) == 1 + 4001 and float(rows[-1][0]) == pytest.approx(0.4)
    assert png_path.read_bytes()[:4] == b'\x89PNG'


def test_simulate_from_a_closed_valve_with_a_ramp():
    measures = json.loads(
        valve_sim(
            'simulate',
            '--json',
            '--initial-flow',
            '0',
            '--final-flow',
            '20L/min',
            '--ramp-time',
            '0.05',
            '--step-time',
            '0.1',
            '--end-time',
            '1.2',
        ).stdout
    )
    assert measures['P_o_percent'] is None and 'zero' in measures['reasons']['P_o_percent']


@pytest.mark.parametrize(
    'args, message',
    [
        (('--set', 'm_m=-1'), 'main_valve_mass'),
        (('--set', 'nonsense=1'), "unknown parameter 'nonsense'"),
        (('--set', 'm_m'), 'NAME=VALUE'),
        (('--params', '/nonexistent/params.yaml'), 'cannot read parameter file'),
        (('--initial-flow=-5L/min',), 'flow must be in [0, '),
        (('--initial-flow', '-5L/min'), 'flow must be in [0, '),  # a value, not an option
        (('--tank-pressure', '-2bar'), 'below vacuum'),
        (('--final-flow', 'lots'), 'not a flow'),
        (('--step-size', '1e-3'), 'step size'),
        # a valve no sub-step the integrator allows can follow: refused before the run
        # (a 1 mm^3 poppet chamber, once this test's example, integrates now: issue 40)
        (('--set', 'm_m=1e-4', '--set', 'main_valve_damping=1e4', '--set', 'V_p=1e-9',
          '--set', 'bulk_modulus=1e10', '--step-size', '1e-4'), 'cannot be integrated at step'),
    ],
)
def test_bad_input_is_one_clear_line(args, message):
    result = valve_sim('simulate', *args, check=False)
    assert result.returncode != 0
    assert message in result.stderr and 'Traceback' not in result.stderr


def test_study_holds_the_preset_and_writes_the_papers_tables_and_figures(tmp_path):
    result = valve_sim('study', '--out', str(tmp_path))
    assert '26/26 runs' in result.stderr and 'protocol held-preset' in result.stderr
    with open(tmp_path / 'sensitivity.csv') as stream:
        rows = list(csv.DictReader(stream))
    assert list(rows[0])[:3] == ['parameter', 'variation_percent', 'protocol']
    assert set(MEASURE_NAMES) <= set(rows[0])
    assert len(rows) == 30
    assert {row['parameter'] for row in rows} == {'m_m', 'm_p', 'V_p', 'V_c', 'd_c', 'k_p'}
    references = [row for row in rows if row['variation_percent'] == '0']
    assert all(row['T_1_ms'] == references[0]['T_1_ms'] for row in references)
    preset = float(rows[0]['preset_pressure_Pa'])
    assert preset == pytest.approx(7e6, rel=1e-3)  # the paper's preset, config/reference.yaml
    for row in rows:
        case = (row['parameter'], row['variation_percent'])
        assert row['protocol'] == 'held-preset'
        for name in MEASURE_NAMES:  # every case relieves and has all six measures
            assert row[name] != '', (case, name, row['reasons'])
        assert float(row['initial_main_valve_displacement_m']) > 0.0, case  # main stage open
        assert float(row['envelope_decay_per_s']) > 0.0, case  # T_s's companion
        # The preset held: the case cracks at it, and p_s before the step reads the preset
        # plus the override from cracking to 5 L/min.
        assert float(row['cracking_pressure_Pa']) == pytest.approx(preset, rel=1e-6), case
        assert preset < float(row['initial_supply_pressure_Pa']) < 1.01 * preset, case
    k_p_rows = [row for row in rows if row['parameter'] == 'k_p']
    initial = [float(row['initial_supply_pressure_Pa']) for row in k_p_rows]
    # Only the override from cracking to 5 L/min moves with k_p (0.13 %); a frozen preload
    # would move p_s by about +-20 %.
    assert max(initial) - min(initial) < 5e-3 * preset
    k_p_preloads = [float(row['pilot_spring_preload_m']) for row in k_p_rows]
    assert k_p_preloads == sorted(k_p_preloads, reverse=True)  # stiffer spring, less preload
    with open(tmp_path / 'table3.csv') as stream:
        table3 = list(csv.DictReader(stream))
    assert [row['measure'] for row in table3] == [*MEASURE_NAMES, 'envelope_decay_per_s']
    assert list(table3[0]) == [
        'measure',
        'table1',
        'table2',
        'relative_change_percent',
        'protocol',
    ]
    for number in (6, 7, 8, 9, 10, 11, 12, 13):
        assert len(list(tmp_path.glob(f'figure{number:02d}_*.png'))) == 1


def test_frozen_preload_protocol_lets_the_preset_move_with_the_spring(reference):
    from valve_sim.analysis.studies.cases import run_case

    held = run_case(reference, {'k_p': 20}, 1e-5, 'held-preset', 7e6)['case']
    frozen = run_case(reference, {'k_p': 20}, 1e-5, 'frozen-preload')['case']
    assert frozen['protocol'] == 'frozen-preload' and held['protocol'] == 'held-preset'
    assert frozen['pilot_spring_preload_m'] == reference['pilot_spring_preload']
    # p_s before the step: the preset plus the override from cracking to 5 L/min (0.3 %).
    assert held['initial_supply_pressure_Pa'] == pytest.approx(7e6, rel=5e-3)
    assert frozen['initial_supply_pressure_Pa'] > 1.15 * held['initial_supply_pressure_Pa']


def test_preset_pressure_on_the_command_line_and_in_parameter_files(tmp_path):
    out = valve_sim('operating-point', '--flow', '5L/min', '--preset-pressure', '8MPa').stdout
    assert 'cracking pressure: 8.0000 MPa' in out
    path = tmp_path / 'rig.yaml'
    path.write_text('relief_valve:\n  ros__parameters:\n    preset_pressure: 6.5e6\n')
    out = valve_sim('operating-point', '--flow', '5L/min', '--params', str(path)).stdout
    assert 'cracking pressure: 6.5000 MPa' in out
    out = valve_sim('operating-point', '--flow', '5L/min', '--set', 'preset_pressure=9e6').stdout
    assert 'cracking pressure: 9.0000 MPa' in out
    bad = valve_sim('simulate', '--preset-pressure', '0.5GPa', check=False)
    assert bad.returncode != 0 and 'not a pressure' in bad.stderr
    bad = valve_sim('simulate', '--preset-pressure', '900MPa', check=False)
    assert bad.returncode != 0 and 'preset_pressure' in bad.stderr


def test_operating_point_reports_balances_and_modes():
    out = valve_sim('operating-point', '--flow', '5L/min').stdout
    assert 'cracking pressure: 7.0000 MPa' in out  # the paper's preset
    assert 'p_s 7.0' in out and 'linear modes' in out and 'zeta' in out


def test_a_negative_value_follows_its_option_as_a_separate_argument():
    argv = ['operating-point', '--tank-pressure', '-0.5bar', '--flow', '-.5', '--', '-1']
    assert negative_values_joined(argv) == [
        'operating-point', '--tank-pressure=-0.5bar', '--flow=-.5', '--', '-1'
    ]
    assert negative_values_joined(['--set=x', '-5', '-h']) == ['--set=x', '-5', '-h']
    document = json.loads(
        valve_sim('operating-point', '--tank-pressure', '-0.5bar', '--json').stdout
    )
    assert document['operating_points'][0]['tank_pressure'] == -0.5e5  # below ambient


def test_operating_point_json_has_the_documented_keys_and_the_pilot_flow_is_small():
    document = json.loads(valve_sim('operating-point', '--json').stdout)
    assert document['cracking_pressure'] == pytest.approx(7e6, rel=1e-6)
    low, high = document['operating_points']
    assert low['inlet_flow'] == pytest.approx(5e-3 / 60) and high['inlet_flow'] == pytest.approx(
        20e-3 / 60
    )
    assert set(low) == {
        'inlet_flow',
        'tank_pressure',
        'pressures',
        'openings',
        'flows',
        'main_valve_forces',
        'poppet_forces',
        'modes',
    }
    assert set(low['flows']) == {
        'main', 'pilot', 'bearings', 'damping_orifice', 'rod_leakage', 'relief'
    }
    assert set(low['main_valve_forces']) >= {'tank'} and set(low['poppet_forces']) >= {'tank'}
    for point in (low, high):
        flows = point['flows']
        assert flows['main'] + flows['pilot'] == pytest.approx(point['inlet_flow'], rel=1e-8)
        assert flows['relief'] == pytest.approx(point['inlet_flow'], rel=1e-8)
        assert flows['pilot'] == pytest.approx(
            flows['damping_orifice'] + flows['rod_leakage'], rel=1e-8
        )
        assert sum(point['main_valve_forces'].values()) == pytest.approx(0.0, abs=1e-6)
        assert sum(point['poppet_forces'].values()) == pytest.approx(0.0, abs=1e-6)
        assert all(mode['damping_ratio'] > 0.0 for mode in point['modes'])
    assert low['flows']['pilot'] <= 1.2e-3 / 60  # the valve's design aim: a small pilot flow
    assert low['openings']['main_valve'] > 0.0  # the main stage relieves at 5 L/min


def test_offline_bag_analyses_to_the_offline_measures(tmp_path):
    bag = tmp_path / 'run.mcap'
    start = ('--start-time', '2026-11-29T12:00:00Z')  # 1795953600 s since the epoch
    direct = json.loads(valve_sim('simulate', '--json', '--mcap', str(bag), *start).stdout)
    (step,) = json.loads(valve_sim('analyse', str(bag), '--json').stdout)['steps']
    assert step['t_step'] == pytest.approx(1795953600.25, abs=1e-6)
    assert step['T_1_ms'] == pytest.approx(
        direct['T_1_ms'], abs=0.2
    )  # 1 kHz bag vs 10 kHz samples
    for name in ('P_o_percent', 'P_1_percent', 'r_d', 'T_d_ms', 'T_s_ms'):
        assert step[name] == pytest.approx(direct[name], rel=0.02), name


# What building a parser must not load, so that `valve-sim CMD --help` and argument errors
# stay quick (issue 8; bench/bench_cli.py measures the time).
HEAVY_MODULES = ('numba', 'scipy', 'matplotlib', 'dask', 'distributed', 'rclpy')
# Run each argv (one per argument) through cli.main; print {argv: [exit code, heavy modules]}.
PARSE_ONLY = f"""
import contextlib, io, json, sys
from valve_sim.commands.cli import main
report = {{}}
for argv in sys.argv[1:]:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        try:
            main(argv.split())
        except SystemExit as stop:
            code = stop.code
    loaded = {{name.split('.')[0] for name in sys.modules}} & {set(HEAVY_MODULES)!r}
    report[argv] = [code, sorted(loaded)]
print(json.dumps(report))
"""


@pytest.mark.parametrize('command', [None, *SUBCOMMANDS])
def test_help_and_argument_errors_import_no_heavy_module(command):
    """`valve-sim [CMD] --help` exits 0 and `CMD --no-such-option` 2, loading no HEAVY_MODULES."""
    runs = ['--help'] if command is None else [f'{command} --help', f'{command} --no-such-option']
    result = subprocess.run(
        [sys.executable, '-c', PARSE_ONLY, *runs], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report == {argv: [0 if argv.endswith('--help') else 2, []] for argv in runs}
    usage = valve_sim(*runs[0].split()).stdout
    assert usage.startswith('usage: valve-sim' + (f' {command}' if command else ''))


def test_paper_column_only_beside_the_papers_step():
    other = valve_sim('simulate', '--final-flow', '30L/min', '--end-time', '0.3').stdout
    assert other.splitlines()[0].split() == ['measure', 'valve_sim']
    table2 = valve_sim('simulate', '--params', str(TABLE2), '--end-time', '0.3').stdout
    assert 'paper' not in table2.splitlines()[0]


def test_a_path_that_cannot_be_written_is_named(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('')
    result = valve_sim('study', '--out', str(blocker / 'out'), check=False)
    assert result.returncode == 1
    assert result.stderr.strip() == (
        f'valve-sim study: error: output folder {blocker / "out"} cannot be created: '
        'Not a directory'
    )
    csv_path = blocker / 'run.csv'
    result = valve_sim('simulate', '--end-time', '0.3', '--csv', str(csv_path), check=False)
    assert result.returncode == 1
    assert result.stderr.strip() == f'valve-sim simulate: error: {csv_path}: Not a directory'
