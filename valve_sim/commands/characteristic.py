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
Static pressure-flow characteristic: a slow flow ramp up and down, as on a test rig.

The valve starts empty and closed; the inlet flow rises linearly from 0 to
--max-flow over --ramp-time, is held for --hold-time and falls back to 0 over
--ramp-time. The ramp is analysed by valve_sim.analysis.characteristic (cracking,
rated-flow and reseat pressures, override, hysteresis; docs/characteristic.md)
and compared with the exact steady-state curve. Writes into --out:
  characteristic.csv   time, inlet flow, supply pressure, main-stage flow, ramp
  steady_state.csv     the exact steady-state curve p_s(q_in) and its main-stage flow
  characteristic.json  the marks of the ramp and of the steady state
  characteristic.png   p_s against q_in with the marks and the steady-state curve
"""

import csv
from pathlib import Path
import sys

import numpy as np
from valve_sim.analysis.characteristic import (
    marks_table,
    ramp_test,
    split_ramps,
    steady_marks,
)
from valve_sim.commands.options import (
    add_options,
    check_bag_arguments,
    flow_value,
    load_from_arguments,
    number,
)
from valve_sim.core.errors import ParameterError
from valve_sim.core.flow_step import LITRE_PER_MINUTE
from valve_sim.core.output_files import json_text, make_folder, replacing, write_text

# The model's modules (numba, scipy) are imported in the functions that run it, so that
# `valve-sim characteristic --help` stays quick.


STEADY_POINTS = 80  # points of the steady-state curve


def add_arguments(parser):
    add_options(parser, '--params', '--set', '--preset-pressure')
    parser.add_argument('--max-flow', type=flow_value, default=20.0 * LITRE_PER_MINUTE,
                        metavar='Q',
                        help="top of the ramp (default 20L/min, the paper's largest flow)")
    parser.add_argument('--rated-flow', type=flow_value, metavar='Q',
                        help='rated flow of the valve: the override is taken at it and cracking '
                        'at 1 %% of it (default: --max-flow)')
    parser.add_argument('--ramp-time', type=number('a time', 's', 0.01, 600.0), default=10.0,
                        metavar='S',
                        help='duration of each ramp, up and down [s] (default 10; slower is '
                        'closer to static)')
    parser.add_argument('--hold-time', type=number('a time', 's', 0.0, 600.0), default=0.5,
                        metavar='S',
                        help='time held at --max-flow between the ramps [s] (default 0.5)')
    add_options(parser, '--step-size')
    parser.add_argument('--record-interval', type=number('an interval', 's', 1e-7, 1.0),
                        default=1e-3, metavar='S',
                        help="sample interval of the output [s] (default 1e-3, a rig's 1 kHz)")
    add_options(parser, '--out', required=False, help='write CSV, JSON and the figure here')
    add_options(parser, '--json', help='print the marks as JSON')
    add_options(parser, '--mcap',
                help="also write the ramp as a rosbag2 MCAP file in valve_node's layout (for "
                'valve-sim analyse --characteristic)')
    add_options(parser, '--bag-folder', '--start-time')


def _check(args, step_size):
    if not 0.0 < args.max_flow:
        raise ParameterError('--max-flow must be > 0')
    if not 0.01 <= args.ramp_time <= 600.0 or not 0.0 <= args.hold_time <= 600.0:
        raise ParameterError('need 0.01 <= --ramp-time <= 600 s and 0 <= --hold-time <= 600 s')
    if not step_size <= args.record_interval <= 1.0:
        raise ParameterError(f'--record-interval must be in [{step_size:g}, 1] s')
    rated = args.rated_flow or args.max_flow
    if not 0.0 < rated <= args.max_flow:
        raise ParameterError('--rated-flow must be > 0 and <= --max-flow')
    return rated


def _write_csv(path, header, rows):
    with replacing(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(header)
        writer.writerows(rows)


def _ramp_labels(inlet_flow):
    rising, falling = split_ramps(inlet_flow)
    labels = np.full(len(inlet_flow), 'top', dtype=object)
    labels[rising[:-1]], labels[falling[1:]] = 'rising', 'falling'
    return labels


def run(args):
    check_bag_arguments(args)
    loaded = load_from_arguments(args)
    params, settings = loaded.params, loaded.settings
    step_size = settings['step_size']
    rated = _check(args, step_size)
    waveforms, main, marks = ramp_test(
        params, args.max_flow, rated, args.ramp_time, args.hold_time, step_size,
        args.record_interval,
    )
    steady = steady_marks(params, rated, args.max_flow)
    report = {
        'max_flow': args.max_flow,
        'rated_flow': rated,
        'ramp_time': args.ramp_time,
        'hold_time': args.hold_time,
        'step_size': step_size,
        'ramp': {basis: found.as_dict() for basis, found in marks.items()},
        'steady_state': steady,
    }
    if args.out:
        write_outputs(Path(args.out), params, waveforms, main, marks['main_stage_flow'], steady,
                      report, args.max_flow)
    if args.mcap:
        from valve_sim.core.simulation import relief_flows
        from valve_sim.recording.valve_topics import write_simulation_bag

        write_simulation_bag(
            args.mcap, waveforms, settings['ambient_pressure'], args.record_interval,
            start_time_ns=args.start_time, folder=args.bag_folder,
            relief=relief_flows(params, waveforms),
        )
    if args.json:
        print(json_text(report))
    else:
        print(marks_table(marks['main_stage_flow'], steady))
        curve = marks['pressure_flow_curve']
        alone = [
            f'{name} {value * 1e-6:.5f} MPa'
            for name, value in (
                ('cracking', curve.cracking_pressure),
                ('reseat', curve.reseat_pressure),
            )
            if value is not None
        ]
        if alone:
            print('from the pressure-flow curve alone (as from a rig bag): ' + ', '.join(alone))
    return 0


def write_outputs(out, params, waveforms, main, marks, steady, report, max_flow):
    """CSV files, JSON and the figure into out."""
    from valve_sim.analysis.plotting import plot_characteristic
    from valve_sim.core.steady_curve import steady_curve

    make_folder(out)
    q_in, p_s = waveforms.inlet_flow, waveforms['supply_pressure']
    _write_csv(
        out / 'characteristic.csv',
        ['time_s', 'inlet_flow_m3_s', 'supply_pressure_Pa', 'main_stage_flow_m3_s', 'ramp'],
        (
            [f'{t:.6f}', f'{q:.9e}', f'{p:.9e}', f'{m:.9e}', label]
            for t, q, p, m, label in zip(waveforms.time, q_in, p_s, main, _ramp_labels(q_in))
        ),
    )
    flows = np.linspace(0.0, max_flow, STEADY_POINTS + 1)[1:]
    pressure, main_steady = steady_curve(params, flows)
    _write_csv(
        out / 'steady_state.csv',
        ['inlet_flow_m3_s', 'supply_pressure_Pa', 'main_stage_flow_m3_s'],
        ([f'{q:.9e}', f'{p:.9e}', f'{m:.9e}'] for q, p, m in zip(flows, pressure, main_steady)),
    )
    write_text(out / 'characteristic.json', json_text(report) + '\n')
    plot_characteristic(out / 'characteristic.png', q_in, p_s, marks, (flows, pressure), steady)
    print(f'wrote {out}/characteristic.csv, steady_state.csv, characteristic.json and '
          'characteristic.png', file=sys.stderr)
