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
Run the valve model offline for one inlet-flow step and report the six measures.

Default: the paper's test (exact steady state at 5 L/min, +15 L/min step at
0.25 s, end at 1.25 s) with config/reference.yaml. Flows accept a unit suffix
(5L/min) and are m^3/s otherwise; times are seconds. Faults and sensor settings
(fault.*, sensor.*: docs/faults.md) come from --set and --params; --faults FILE
schedules them at valve_node's ticks. The tank's pressure (gauge) is held at
--tank-pressure, or stepped to --final-tank-pressure at --tank-step-time (over
--tank-ramp-time), as the inlet flow is. The measures are taken on the model's supply
pressure above the tank, p_s - p_t (p_s itself with the tank at ambient); the sensor
readings are what --mcap records on the pressure topics.
"""

import csv
import math
import sys

from valve_sim.analysis.paper import is_reference_step, REFERENCE_FLOW_STEP
from valve_sim.analysis.recorded_steps import measures_table
from valve_sim.commands.options import (
    add_options,
    check_bag_arguments,
    check_tank_pressure,
    flow_value,
    gauge_pressure_value,
    load_from_arguments,
    namespace_name,
    number,
    plot_path,
)
from valve_sim.core.catalogue import split
from valve_sim.core.errors import ParameterError
from valve_sim.core.faults import HEALTHY
from valve_sim.core.flow_step import FlowStep, TankPressure
from valve_sim.core.input_files import FAULT_SCHEDULE as FAULT_SCHEDULE_FILE, MAX_EVENTS
from valve_sim.core.output_files import json_text, replacing
from valve_sim.core.parameters import FAULT_SCHEDULE, load_parameters

# The model's modules (numba, scipy) are imported in the functions that run it, so that
# `valve-sim simulate --help` stays quick.


STATE_UNITS = ('Pa', 'Pa', 'Pa', 'Pa', 'm', 'm_s', 'm', 'm_s')
MAX_END_TIME = 3600.0  # [s] the longest run
TIME = number('a time', 's', 0.0, MAX_END_TIME)
INTERVAL = number('an interval', 's', 1e-7, 1.0)


def add_arguments(parser):
    add_options(parser, '--params', '--set', '--preset-pressure')
    s = REFERENCE_FLOW_STEP
    parser.add_argument('--initial-flow', type=flow_value, default=s.initial_flow, metavar='Q',
                        help='inlet flow before the step; 0 starts from the closed, empty '
                        'valve (default 5L/min)')
    parser.add_argument('--final-flow', type=flow_value, default=s.final_flow, metavar='Q',
                        help='inlet flow after the step (default 20L/min)')
    parser.add_argument('--step-time', type=TIME, default=s.step_time, metavar='S',
                        help=f'time of the step [s] (default {s.step_time:g})')
    parser.add_argument('--ramp-time', type=TIME, default=0.0, metavar='S',
                        help='change the flow linearly over this time instead of at once [s]')
    parser.add_argument('--end-time', type=TIME, default=s.end_time, metavar='S',
                        help=f'end of the run [s] (default {s.end_time:g})')
    add_options(parser, '--tank-pressure', help="the tank's (return line's) pressure from the "
                'start, gauge (e.g. 1MPa; default: tank_pressure of the parameter file or --set, '
                '0: at ambient): the run starts at its steady state')
    parser.add_argument('--final-tank-pressure', type=gauge_pressure_value, metavar='P',
                        help="the tank's pressure after --tank-step-time, gauge: a back-pressure "
                        'step (default: held at --tank-pressure)')
    parser.add_argument('--tank-step-time', type=TIME, metavar='S',
                        help="time of the tank's step [s] (default: --step-time)")
    parser.add_argument('--tank-ramp-time', type=TIME, default=0.0, metavar='S',
                        help="change the tank's pressure linearly over this time instead [s]")
    add_options(parser, '--step-size')
    parser.add_argument('--record-interval', default=1e-4, metavar='S', type=INTERVAL,
                        help='sample interval of the output waveforms [s] (default 1e-4, '
                        "the paper's)")
    parser.add_argument('--faults', metavar='FILE.yaml',
                        help='fault schedule (docs/faults.md): events at t [s], applied at the '
                        'first tick (1/publish_rate) at or after t, as valve_node does (YAML, '
                        f'{FAULT_SCHEDULE_FILE.limits()}, at most {MAX_EVENTS} events)')
    add_options(parser, '--json', help='print the six measures as JSON')
    parser.add_argument('--csv', metavar='FILE', help='write the waveforms as CSV (SI units)')
    add_options(parser, '--plot', help="draw the paper's Figure 5 (an existing folder: "
                'figure5.png in it)')
    add_options(parser, '--mcap',
                help="write the run as a rosbag2 MCAP file in valve_node's topic layout and time "
                "base (1 kHz ticks, absolute pressures: gauge + the settings' ambient_pressure)")
    parser.add_argument('--rig-topics', metavar='PRESSURE,FLOW',
                        help='with --mcap: write what a test rig records instead, the supply '
                        'pressure and the inlet flow as std_msgs/msg/Float64 on these two '
                        'topics (no main-valve position)')
    parser.add_argument('--pressure-noise', type=number('a pressure', 'Pa', 0.0, 1e8),
                        default=0.0, metavar='PA',
                        help='with --rig-topics: Gaussian noise on the recorded pressure, '
                        'standard deviation [Pa]')
    parser.add_argument('--flow-interval', type=INTERVAL, metavar='S',
                        help='with --rig-topics: sample interval of the flowmeter [s], a whole '
                        'multiple of the record interval (default: the pressure interval, '
                        '1 ms; e.g. 0.01 for a 100 Hz flowmeter)')
    add_options(parser, '--seed', help='seed of the --pressure-noise generator')
    add_options(parser, '--bag-folder', '--start-time')
    parser.add_argument('--namespace', metavar='NS',
                        help='the valve as valve_node in this namespace (e.g. /rig1): the '
                        '--params sections that apply to it, and with --mcap its topics '
                        'below it (default: the root namespace)')


def write_mcap(args, waveforms, ambient_pressure, publish_interval, readings, relief):
    """
    Write --mcap (valve_topics.write_simulation_bag), as --bag-folder and --start-time say.

    With --rig-topics: what a rig records (valve_topics.write_rig_bag).
    readings: the sensor stage's pressures per tick (nan: nothing published);
    relief: the relief flows per sample (simulation.relief_flows).
    """
    from valve_sim.recording.valve_topics import write_rig_bag, write_simulation_bag

    if args.rig_topics:
        pressure_topic, flow_topic = rig_topics(args.rig_topics)
        if not (math.isfinite(args.pressure_noise) and args.pressure_noise >= 0.0):
            raise ParameterError(
                f'--pressure-noise must be finite and >= 0 Pa, got {args.pressure_noise}'
            )
        write_rig_bag(
            args.mcap, waveforms, pressure_topic, flow_topic, ambient_pressure,
            args.pressure_noise, args.seed, publish_interval, start_time_ns=args.start_time,
            folder=args.bag_folder, flow_interval=args.flow_interval,
        )
        return
    write_simulation_bag(
        args.mcap, waveforms, ambient_pressure, publish_interval, start_time_ns=args.start_time,
        folder=args.bag_folder, readings=readings, namespace=namespace_name(args.namespace),
        relief=relief,
    )


def rig_topics(text):
    """'PRESSURE,FLOW' of --rig-topics -> two absolute topic names; ParameterError if not."""
    topics = [topic.strip() for topic in text.split(',')]
    if len(topics) != 2 or not all(topics) or topics[0] == topics[1]:
        raise ParameterError(
            f'--rig-topics needs two different topics PRESSURE,FLOW, got {text!r}'
        )
    return ['/' + topic.lstrip('/') for topic in topics]


def flow_step_of(args):
    if not args.step_time < args.end_time:
        raise ParameterError('need --step-time < --end-time')
    return FlowStep(
        args.initial_flow, args.final_flow, args.step_time, args.end_time, args.ramp_time
    )


def tank_profile(args, params, settings):
    """Return the TankPressure of --tank-pressure (settings), --final-tank-pressure, its times."""
    step_time = args.step_time if args.tank_step_time is None else args.tank_step_time
    if not 0.0 <= step_time <= args.end_time or not args.tank_ramp_time >= 0.0:
        raise ParameterError('need 0 <= --tank-step-time <= --end-time and --tank-ramp-time >= 0')
    if args.final_tank_pressure is not None:
        check_tank_pressure(args.final_tank_pressure, params, settings)
    return TankPressure(
        settings['tank_pressure'], args.final_tank_pressure, step_time, args.tank_ramp_time
    )


def write_csv(path, waveforms, relief):
    """
    Waveforms as CSV, SI units in the header.

    Time, the applied inlet flow, the eight states, the applied tank pressure (gauge)
    and the flows to the tank (relief: simulation.relief_flows); the columns before
    the tank's are those of the runs before it existed.
    """
    from valve_sim.core.model import STATE_NAMES
    from valve_sim.core.simulation import RELIEF_COLUMNS

    header = (
        ['time_s', 'inlet_flow_m3_s']
        + [f'{name}_{unit}' for name, unit in zip(STATE_NAMES, STATE_UNITS)]
        + ['tank_pressure_Pa']
        + [f'{name}_m3_s' for name in RELIEF_COLUMNS]
    )
    with replacing(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(header)
        for t, q, p_t, state, flows in zip(
            waveforms.time, waveforms.inlet_flow, waveforms.tank_pressure, waveforms.states,
            relief,
        ):
            writer.writerow(
                [f'{t:.7f}', f'{q:.9e}']
                + [f'{v:.9e}' for v in (*state, p_t, *flows)]
            )


def load_injection(args, injection):
    """(FaultSet, sensor settings, schedule events) from --set/--params and --faults."""
    from valve_sim.core.fault_schedule import load_schedule
    from valve_sim.core.sensors import checked_settings, default_settings

    change = split(injection)
    faults = HEALTHY.changed(change.fault)
    sensors = checked_settings(default_settings(), change.sensor)
    path = args.faults or change.schedule.get(FAULT_SCHEDULE)
    return faults, sensors, load_schedule(path) if path else []


def is_papers_run(params, flow_step):
    """Whether a run is the paper's Figure 5 case: its step, on the reference parameters."""
    return (
        is_reference_step(flow_step.initial_flow, flow_step.final_flow)
        and flow_step.ramp_time == 0.0
        and params == load_parameters().params
    )


def run(args):
    from valve_sim.analysis.steps.simulated_step import measure_run
    from valve_sim.core.sensors import read_waveforms
    from valve_sim.core.simulation import relief_flows, simulate
    from valve_sim.recording.valve_topics import publish_interval_for

    check_bag_arguments(args)
    if args.flow_interval is not None and not (args.mcap and args.rig_topics):
        raise ParameterError('--flow-interval needs --mcap and --rig-topics')
    loaded = load_from_arguments(args, with_injection=True)
    params, settings = loaded.params, loaded.settings
    faults, sensors, schedule = load_injection(args, loaded.injection)
    step_size = settings['step_size']
    flow_step = flow_step_of(args)
    tank = tank_profile(args, params, settings)
    if args.record_interval < step_size:
        raise ParameterError(f'--record-interval must be >= the step size ({step_size:g} s)')
    waveforms = simulate(
        params,
        flow_step,
        step_size,
        args.record_interval,
        faults,
        schedule,
        1.0 / settings['publish_rate'],
        halt_on_overpressure=True,
        tank=tank,
    )
    schedule_file = args.faults or loaded.injection.get(FAULT_SCHEDULE)
    measured = measure_run(
        params, waveforms, flow_step, faults, schedule_file if schedule else None
    )
    measures, above_tank = measured.measures, measured.above_tank
    for alarm in measured.alarms:
        print(f'valve-sim simulate: warning: {alarm}', file=sys.stderr)
    written = args.csv or args.plot or args.mcap
    relief = relief_flows(params, waveforms, faults) if written else None
    if args.csv:
        write_csv(args.csv, waveforms, relief)
    if args.plot:
        from valve_sim.analysis.plotting import plot_step_response

        plot_step_response(
            plot_path(args.plot, 'figure5.png'),
            waveforms.time,
            waveforms['supply_pressure'] - waveforms.tank_pressure,
            waveforms['main_valve_displacement'],
            waveforms['poppet_displacement'],
            flow_step.step_time,
            measures.as_dict(),
            flows={'inlet': waveforms.inlet_flow, 'relief': relief[:, 0]},
            pressure='p_s - p_t' if above_tank else 'p_s',
        )
    if args.mcap:
        interval = publish_interval_for(args.record_interval)
        _, readings = read_waveforms(waveforms, sensors, interval, settings['ambient_pressure'])
        write_mcap(args, waveforms, settings['ambient_pressure'], interval, readings, relief)
    if args.json:
        print(json_text(measures.as_dict()))
    else:
        paper = is_papers_run(params, flow_step) and not measured.faulty and not above_tank
        print(measures_table(measures, paper=paper))
        if above_tank:
            print(
                f'tank pressure {tank.initial:g} Pa (gauge)'
                + (f', {tank.final:g} Pa from t = {tank.step_time:g} s' if tank.final is not None
                   else '')
                + '; measures of the supply pressure above the tank, p_s - p_t'
            )
        if faults.active():
            print(f'faults from the start: {faults.describe()}')
        for applied_at, changes in waveforms.events:
            print(f'at t = {applied_at:.6f} s: {changes}')
    if waveforms.halted:
        print(f'valve-sim simulate: {measures.details["overpressure"]["message"]}; the outputs '
              'show it so', file=sys.stderr)
        return 1
    return 0
