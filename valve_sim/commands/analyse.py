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
Step measures of each inlet-flow step in a rosbag2 MCAP file or bag folder, as measured live.

Reads the signals of valve_sim.analysis.steps.signals (topics mappable by option, so a real rig's
bag with other names or types works), joined on the supply-pressure times
(valve_sim.recording.signal_reader), and measures each step with
valve_sim.analysis.recorded_steps (step_analysis.StepAnalysis over them). A file whose end is
missing (a recording killed before it closed) gives what its complete chunks
hold, with a warning; a damaged or foreign file is an error.

With --characteristic the bag is a slow flow ramp up and down instead (as
valve-sim characteristic makes one): only supply pressure and inlet flow are
needed, and valve_sim.analysis.characteristic finds cracking and reseat from the
pressure-flow curve (a bag holds no main-stage flow; docs/characteristic.md).

Where the bag holds the tank's pressure (valve_node's applied_tank_pressure, or a rig's
topic by --topic-tank-pressure), the measures and the characteristic take the supply
pressure above the tank, p_s - p_t (valve_sim.analysis.steps.step_analysis); the relief flow,
where recorded, is reported beside the inlet flow and drawn under the pressures.
"""

import sys

import numpy as np
from valve_sim.analysis.recorded_steps import analyse, analyse_step, plot_steps, steps_text
from valve_sim.commands.options import (
    add_options,
    add_signal_arguments,
    flow_value,
    number,
    plot_path,
    signal_map_from,
)
from valve_sim.core.errors import InputFileError
from valve_sim.core.output_files import json_text
from valve_sim.recording.signal_reader import BAG_REQUIRED, read_recording


def add_arguments(parser):
    parser.add_argument('bag', metavar='BAG',
                        help="rosbag2 MCAP file or bag folder (valve_node's topics, or "
                        'mapped ones)')
    add_options(parser, '--json', help='print the step records as JSON')
    add_options(parser, '--plot', help='draw Figure 5 of each step (FILE_step<k>.png for '
                'several; an existing folder: figure5.png in it)')
    add_signal_arguments(parser)
    parser.add_argument('--step-threshold', default=1e-6, metavar='Q',
                        type=number('a flow', 'm^3/s', 0.0, 1.0, low_open=True),
                        help='smallest inlet-flow change taken as a step [m^3/s] (default 1e-6; '
                        'in (0, 1])')
    parser.add_argument('--step-time', type=number('a time', 's', 0.0, 1e12), metavar='S',
                        help="analyse one step at this time [s, on the bag's time axis, inside "
                        'the recording] instead of detecting steps; the inlet flow is then not '
                        'needed')
    parser.add_argument('--characteristic', action='store_true',
                        help='the bag is a slow flow ramp up and down: report the static '
                        'characteristic (cracking, rated-flow and reseat pressures, override, '
                        'hysteresis) instead of steps')
    parser.add_argument('--rated-flow', type=flow_value, metavar='Q',
                        help='with --characteristic: rated flow of the valve (default: the '
                        'largest inlet flow in the bag)')
    parser.add_argument('--step-direction', choices=('up', 'down'), default='up',
                        help='direction of the inlet-flow change at --step-time (default up)')


def run_characteristic(args):
    """--characteristic: the static characteristic of a recorded ramp."""
    from valve_sim.analysis.characteristic import characteristic

    recording = read_recording(
        args.bag, signal_map_from(args), ('supply_pressure', 'inlet_flow')
    )
    if recording.problem:
        print(f'valve-sim analyse: warning: {recording.problem}', file=sys.stderr)
    rated = args.rated_flow or float(np.max(recording.inlet_flow))
    if not rated > 0.0:
        raise InputFileError(f'{args.bag}: the inlet flow is never above 0 (no ramp)')
    try:
        marks = characteristic(recording.valve_pressure(), recording.inlet_flow, rated)
    except ValueError as error:
        raise InputFileError(f'{args.bag}: {error}') from error
    if args.plot:
        from valve_sim.analysis.plotting import plot_characteristic

        plot = plot_path(args.plot, 'characteristic.png')
        plot_characteristic(
            plot,
            recording.inlet_flow,
            recording.valve_pressure(),
            marks,
            title=f'Static characteristic of {args.bag}',
        )
        print(f'wrote {plot}', file=sys.stderr)
    above_tank = bool(np.any(np.isfinite(recording.tank_pressure)))
    if args.json:
        document = {'bag': str(args.bag), 'characteristic': marks.as_dict()}
        if above_tank:
            document['pressure'] = 'supply above the tank'
        print(json_text(document))
    else:
        from valve_sim.analysis.characteristic import marks_table

        print(
            f'{args.bag}: static characteristic, cracking and reseat from {marks.basis}'
            + (' (pressures: the supply above the recorded tank pressure)' if above_tank else '')
        )
        print(marks_table(marks))
    return 0


def run(args):
    if args.characteristic:
        return run_characteristic(args)
    required = BAG_REQUIRED if args.step_time is None else ('supply_pressure',)
    recording = read_recording(args.bag, signal_map_from(args), required)
    if recording.problem:
        print(f'valve-sim analyse: warning: {recording.problem}', file=sys.stderr)
    if args.step_time is None:
        records = analyse(recording, args.step_threshold)
    elif not recording.time[0] <= args.step_time < recording.time[-1]:
        raise InputFileError(
            f'--step-time {args.step_time:g} s is outside the recording of {args.bag} '
            f'(t from {recording.time[0]:.6f} to {recording.time[-1]:.6f} s)'
        )
    else:
        records = [
            analyse_step(recording, args.step_time, 1 if args.step_direction == 'up' else -1)
        ]
    if args.plot and records:
        for target in plot_steps(plot_path(args.plot, 'figure5.png'), recording, records):
            print(f'wrote {target}', file=sys.stderr)
    if args.json:
        print(json_text({'bag': str(args.bag), 'steps': records}))
    elif records:
        print(steps_text(records, recording))
    else:
        print(
            f'no inlet-flow step in {args.bag} ({len(recording.time)} samples, '
            f'{recording.time[-1] - recording.time[0]:.3f} s)'
        )
    return 0
