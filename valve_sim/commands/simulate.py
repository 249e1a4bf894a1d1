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
schedules them at valve_node's ticks. The measures are taken on the model's p_s; the
sensor readings are what --mcap records on the pressure topics.
"""

from argparse import ArgumentTypeError
import csv
from datetime import datetime, timezone
import json
import math
import time

from valve_sim.analysis.measures import MEASURE_NAMES, step_measures
from valve_sim.analysis.paper import FIGURE5_MEASURES, is_reference_step, REFERENCE_SCENARIO
from valve_sim.core.fault_schedule import load_schedule
from valve_sim.core.faults import FAULT_NAMES, HEALTHY
from valve_sim.core.model import STATE_NAMES
from valve_sim.core.parameters import check_value, FAULT_SCHEDULE, load_parameters, ParameterError
from valve_sim.core.sensors import checked_settings, default_settings, read_waveforms
from valve_sim.core.simulation import LITRE_PER_MINUTE, Scenario, simulate
from valve_sim.core.steady_state import with_preset_pressure


STATE_UNITS = ('Pa', 'Pa', 'Pa', 'Pa', 'm', 'm_s', 'm', 'm_s')


def quantity(text, units, kind, example):
    """Parse a number with an optional unit suffix of units {suffix: factor to SI} -> SI."""
    number, factor = text.strip(), 1.0
    for suffix, scale in units.items():
        if number.endswith(suffix):
            number, factor = number[: -len(suffix)], scale
            break
    try:
        return float(number) * factor
    except ValueError:
        raise ArgumentTypeError(f'not a {kind}: {text!r} (use e.g. {example})') from None


def flow_value(text):
    """Parse a volume flow from '8.3e-5', '8.3e-5m^3/s' or '5L/min' -> m^3/s (argparse type)."""
    units = {'L/min': LITRE_PER_MINUTE, 'l/min': LITRE_PER_MINUTE, 'm^3/s': 1.0, 'm3/s': 1.0}
    value = quantity(text, units, 'flow', '5L/min or 8.33e-5')
    if not math.isfinite(value) or value < 0.0:
        raise ArgumentTypeError(f'flow must be finite and >= 0, got {text!r}')
    return value


def start_time(text):
    """ISO 8601 time (UTC unless it says otherwise) -> ns since the epoch (argparse type)."""
    try:
        moment = datetime.fromisoformat(text.strip().replace('Z', '+00:00'))
    except ValueError:
        raise ArgumentTypeError(f'not an ISO 8601 time: {text!r} (e.g. 2026-11-29T12:00:00Z)')
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=timezone.utc)
    delta = moment - datetime(1970, 1, 1, tzinfo=timezone.utc)
    return (delta.days * 86_400 + delta.seconds) * 1_000_000_000 + delta.microseconds * 1000


def assignment(text):
    """'NAME=VALUE' -> (NAME, value) for --set: true/false, an integer, else a float."""
    name, separator, value = text.partition('=')
    if not separator:
        raise ArgumentTypeError(f'expected NAME=VALUE, got {text!r}')
    if value.strip().lower() in ('true', 'false'):
        return name.strip(), value.strip().lower() == 'true'
    if name.strip() == FAULT_SCHEDULE:
        return name.strip(), value.strip()
    try:
        return name.strip(), int(value) if value.strip().isdigit() else float(value)
    except ValueError:
        raise ArgumentTypeError(f'value of {name.strip()!r} is not a number: {value!r}') from None


def pressure_value(text):
    """Parse a pressure from '7e6', '7e6Pa', '7MPa' or '70bar' -> Pa (argparse type)."""
    units = {'MPa': 1e6, 'kPa': 1e3, 'bar': 1e5, 'Pa': 1.0}
    value = quantity(text, units, 'pressure', '7MPa or 7e6')
    if not math.isfinite(value) or value <= 0.0:
        raise ArgumentTypeError(f'pressure must be finite and > 0, got {text!r}')
    return value


def add_parameter_arguments(parser):
    """--params, --set and --preset-pressure, shared by every command that runs the model."""
    parser.add_argument(
        '--params',
        metavar='FILE.yaml',
        help='ROS 2 parameter file overlaid on config/reference.yaml (e.g. config/table2.yaml)',
    )
    parser.add_argument(
        '--set',
        metavar='NAME=VALUE',
        type=assignment,
        action='append',
        default=[],
        help='override one parameter (ROS name or paper symbol, SI units; simulate also '
        'takes fault.* and sensor.* settings, true/false for switches); repeatable',
    )
    parser.add_argument(
        '--preset-pressure',
        type=pressure_value,
        metavar='P',
        help='main-valve cracking pressure (gauge, e.g. 7MPa): sets pilot_spring_preload like '
        'the adjusting screw, after --params and --set (also preset_pressure in a file or --set)',
    )


def load_from_arguments(args, injection=None):
    """
    Return (params, settings) from --params, --set, --preset-pressure and --step-size.

    --step-size overrides settings["step_size"]; fault and sensor settings go into the
    dict injection (without one they are refused). A preset pressure (--preset-pressure,
    else preset_pressure of --set or the file) sets the pilot spring preload last.
    """
    params, settings = load_parameters(args.params, dict(args.set), injection)
    preset = settings.pop('preset_pressure', None)
    preset = getattr(args, 'preset_pressure', None) or preset
    if preset is not None:
        params = with_preset_pressure(params, check_value('preset_pressure', preset))
    if getattr(args, 'step_size', None):
        settings['step_size'] = args.step_size
    if not 1e-7 <= settings['step_size'] <= 1e-4:
        raise ParameterError(f'step size {settings["step_size"]:g} s is outside [1e-07, 0.0001] s')
    return params, settings


def add_arguments(parser):
    add_parameter_arguments(parser)
    s = REFERENCE_SCENARIO
    parser.add_argument(
        '--initial-flow',
        type=flow_value,
        default=s.initial_flow,
        metavar='Q',
        help='inlet flow before the step; 0 starts from the closed, empty valve (default 5L/min)',
    )
    parser.add_argument(
        '--final-flow',
        type=flow_value,
        default=s.final_flow,
        metavar='Q',
        help='inlet flow after the step (default 20L/min)',
    )
    parser.add_argument(
        '--step-time', type=float, default=s.step_time, metavar='S', help='time of the step [s]'
    )
    parser.add_argument(
        '--ramp-time',
        type=float,
        default=0.0,
        metavar='S',
        help='change the flow linearly over this time instead of at once [s]',
    )
    parser.add_argument(
        '--end-time', type=float, default=s.end_time, metavar='S', help='end of the run [s]'
    )
    parser.add_argument(
        '--step-size',
        type=float,
        metavar='S',
        help='RK4 step [s] (default: step_size of the parameter file, 1e-5)',
    )
    parser.add_argument(
        '--record-interval',
        type=float,
        default=1e-4,
        metavar='S',
        help="sample interval of the output waveforms [s] (default 1e-4, the paper's)",
    )
    parser.add_argument(
        '--faults',
        metavar='FILE.yaml',
        help='fault schedule (docs/faults.md): events at t [s], applied at the first tick '
        '(1/publish_rate) at or after t, as valve_node does',
    )
    parser.add_argument('--json', action='store_true', help='print the six measures as JSON')
    parser.add_argument('--csv', metavar='FILE', help='write the waveforms as CSV (SI units)')
    parser.add_argument('--plot', metavar='FILE.png', help="draw the paper's Figure 5")
    parser.add_argument(
        '--mcap',
        metavar='FILE.mcap',
        help="write the run as a rosbag2 MCAP file in valve_node's topic layout and time base "
        "(1 kHz ticks, absolute pressures: gauge + the settings' ambient_pressure)",
    )
    parser.add_argument(
        '--rig-topics',
        metavar='PRESSURE,FLOW',
        help='with --mcap: write what a test rig records instead, the supply pressure and the '
        'inlet flow as std_msgs/msg/Float64 on these two topics (no main-valve position)',
    )
    parser.add_argument(
        '--pressure-noise',
        type=float,
        default=0.0,
        metavar='PA',
        help='with --rig-topics: Gaussian noise on the recorded pressure, standard deviation [Pa]',
    )
    parser.add_argument(
        '--seed', type=int, default=0, metavar='N', help='seed of the --pressure-noise generator'
    )
    add_bag_arguments(parser)


def add_bag_arguments(parser):
    """--bag-folder and --start-time, for the commands that write --mcap."""
    parser.add_argument(
        '--bag-folder',
        action='store_true',
        help='with --mcap: write a rosbag2 bag folder there instead (metadata.yaml + '
        '<folder name>_0.mcap; the folder must not exist yet)',
    )
    parser.add_argument(
        '--start-time',
        type=start_time,
        metavar='UTC',
        help='with --mcap: wall-clock time of model time 0, ISO 8601 (e.g. '
        '2026-11-29T12:00:00Z; default: now, to the millisecond)',
    )


def write_bag(args, waveforms, ambient_pressure, publish_interval, readings=None):
    """
    Write --mcap as --bag-folder and --start-time say (valve_topics.write_simulation_bag).

    With --rig-topics (simulate only): what a rig records (valve_topics.write_rig_bag).
    readings: the sensor stage's pressures per tick (nan: nothing published), if any.
    """
    from valve_sim.recording.valve_topics import write_rig_bag, write_simulation_bag

    start_ns = args.start_time
    if start_ns is None:
        start_ns = time.time_ns() // 1_000_000 * 1_000_000
    if getattr(args, 'rig_topics', None):
        pressure_topic, flow_topic = rig_topics(args.rig_topics)
        if not (math.isfinite(args.pressure_noise) and args.pressure_noise >= 0.0):
            raise ParameterError(
                f'--pressure-noise must be finite and >= 0 Pa, got {args.pressure_noise}'
            )
        write_rig_bag(
            args.mcap,
            waveforms,
            pressure_topic,
            flow_topic,
            ambient_pressure,
            args.pressure_noise,
            args.seed,
            publish_interval,
            start_time_ns=start_ns,
            folder=args.bag_folder,
        )
        return
    write_simulation_bag(
        args.mcap,
        waveforms,
        ambient_pressure,
        publish_interval=publish_interval,
        start_time_ns=start_ns,
        folder=args.bag_folder,
        readings=readings,
    )


def rig_topics(text):
    """'PRESSURE,FLOW' of --rig-topics -> two absolute topic names; ParameterError if not."""
    topics = [topic.strip() for topic in text.split(',')]
    if len(topics) != 2 or not all(topics) or topics[0] == topics[1]:
        raise ParameterError(
            f'--rig-topics needs two different topics PRESSURE,FLOW, got {text!r}'
        )
    return ['/' + topic.lstrip('/') for topic in topics]


def check_bag_arguments(args):
    if (args.bag_folder or args.start_time is not None) and not args.mcap:
        raise ParameterError('--bag-folder and --start-time need --mcap')


def _scenario(args):
    if not 0.0 <= args.step_time < args.end_time or args.ramp_time < 0.0 or args.end_time > 3600.0:
        raise ParameterError('need 0 <= --step-time < --end-time <= 3600 s and --ramp-time >= 0')
    return Scenario(
        args.initial_flow, args.final_flow, args.step_time, args.end_time, args.ramp_time
    )


def write_csv(path, waveforms):
    """Waveforms as CSV: time, applied inlet flow and the eight states, SI units in the header."""
    header = ['time_s', 'inlet_flow_m3_s'] + [
        f'{name}_{unit}' for name, unit in zip(STATE_NAMES, STATE_UNITS)
    ]
    with open(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(header)
        for t, q, state in zip(waveforms.time, waveforms.inlet_flow, waveforms.states):
            writer.writerow([f'{t:.7f}', f'{q:.9e}'] + [f'{v:.9e}' for v in state])


def print_table(measures, paper=False):
    """
    Print the six measures as a table; paper: beside Figure 5's values.

    Only a run of the paper's own scenario should get the paper's column.
    """
    print(f'{"measure":<14}{"valve_sim":>12}' + (f'{"paper":>10}' if paper else ''))
    for name in MEASURE_NAMES:
        value = measures.values[name]
        shown = f'{value:12.4g}' if value is not None else f'{"-":>12}'
        print(f'{name:<14}{shown}' + (f'{FIGURE5_MEASURES[name]:>10.4g}' if paper else ''))
    for name, reason in measures.reasons.items():
        print(f'  {name}: {reason}')


def load_injection(args, injection):
    """(FaultSet, sensor settings, schedule events) from --set/--params and --faults."""
    faults = HEALTHY.changed({n: v for n, v in injection.items() if n in FAULT_NAMES})
    sensors = checked_settings(
        default_settings(),
        {n: v for n, v in injection.items() if n not in FAULT_NAMES and n != FAULT_SCHEDULE},
    )
    path = args.faults or injection.get(FAULT_SCHEDULE)
    return faults, sensors, load_schedule(path) if path else []


def is_papers_run(params, scenario):
    """Whether a run is the paper's Figure 5 case: its step, on the reference parameters."""
    return (
        is_reference_step(scenario.initial_flow, scenario.final_flow)
        and scenario.ramp_time == 0.0
        and params == load_parameters()[0]
    )


def run(args):
    check_bag_arguments(args)
    injection = {}
    params, settings = load_from_arguments(args, injection)
    faults, sensors, schedule = load_injection(args, injection)
    step_size = settings['step_size']
    scenario = _scenario(args)
    if args.record_interval < step_size:
        raise ParameterError(f'--record-interval must be >= the step size ({step_size:g} s)')
    waveforms = simulate(
        params,
        scenario,
        step_size,
        args.record_interval,
        faults,
        schedule,
        1.0 / settings['publish_rate'],
    )
    direction = 1 if scenario.final_flow >= scenario.initial_flow else -1
    measures = step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        scenario.step_time,
        direction,
    )
    faulty = bool(faults.active() or waveforms.events)
    if faulty:
        cause = '; '.join(
            [f'faults from the start: {faults.describe()}'] * bool(faults.active())
            + [f'fault schedule {args.faults or injection.get(FAULT_SCHEDULE)}'] * bool(schedule)
        )
        measures.reasons = {name: f'{why} ({cause})' for name, why in measures.reasons.items()}
    if args.csv:
        write_csv(args.csv, waveforms)
    if args.plot:
        from valve_sim.analysis.plotting import plot_step_response

        plot_step_response(
            args.plot,
            waveforms.time,
            waveforms['supply_pressure'],
            waveforms['main_valve_displacement'],
            waveforms['poppet_displacement'],
            scenario.step_time,
            measures.as_dict(),
        )
    if args.mcap:
        # valve_node's 1 kHz ticks where the samples allow it, else every sample.
        ratio = 1e-3 / args.record_interval
        interval = (
            1e-3 if abs(ratio - round(ratio)) < 1e-9 and ratio >= 1 else args.record_interval
        )
        _, readings = read_waveforms(waveforms, sensors, interval, settings['ambient_pressure'])
        write_bag(args, waveforms, settings['ambient_pressure'], interval, readings)
    if args.json:
        print(json.dumps(measures.as_dict(), indent=2))
    else:
        print_table(measures, paper=is_papers_run(params, scenario) and not faulty)
        if faults.active():
            print(f'faults from the start: {faults.describe()}')
        for applied_at, changes in waveforms.events:
            print(f'at t = {applied_at:.6f} s: {changes}')
    return 0
