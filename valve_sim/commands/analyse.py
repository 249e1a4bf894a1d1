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

Reads the signals of valve_sim.analysis.signals (topics mappable by option, so a real rig's
bag with other names or types works), joins them on the supply-pressure times,
and runs valve_sim.analysis.step_analysis.StepAnalysis over them. A file whose end is
missing (a recording killed before it closed) gives what its complete chunks
hold, with a warning; a damaged or foreign file is an error.

With --characteristic the bag is a slow flow ramp up and down instead (as
valve-sim characteristic makes one): only supply pressure and inlet flow are
needed, and valve_sim.analysis.characteristic finds cracking and reseat from the
pressure-flow curve (a bag holds no main-stage flow; docs/characteristic.md).

Where the bag holds the tank's pressure (valve_node's applied_tank_pressure, or a rig's
topic by --topic-tank-pressure), the measures and the characteristic take the supply
pressure above the tank, p_s - p_t (valve_sim.analysis.step_analysis); the relief flow,
where recorded, is reported beside the inlet flow and drawn under the pressures.
"""

from dataclasses import dataclass
import sys

import numpy as np
from valve_sim.analysis.measures import MEASURE_NAMES, step_measures, StepMeasures, WINDOW
from valve_sim.analysis.signals import (
    CLOCKS,
    Extractor,
    FLUID_PRESSURE,
    Joiner,
    JOINT_STATE,
    ROLE,
    ROLES,
    seconds,
    SignalMap,
)
from valve_sim.analysis.step_analysis import step_record, StepAnalysis, tank_details
from valve_sim.commands.options import (
    add_options,
    flow_value,
    namespace_name,
    number,
    plot_path,
)
from valve_sim.core.errors import InputFileError
from valve_sim.core.output_files import json_text
from valve_sim.core.parameters import SETTING_SPECS, STANDARD_ATMOSPHERE
from valve_sim.recording.bag import BagReader
from valve_sim.recording.rosbag2_metadata import bag_files


# What a bag must hold: a rig records supply pressure and inlet flow, rarely the main valve
# (then T_s comes from the pressure, valve_sim.analysis.measures).
BAG_REQUIRED = ('supply_pressure', 'inlet_flow')
PLOT_LEAD = (
    0.25  # [s] shown before the step, which the plot puts at 0.25 s as in the paper's Figure 5
)


@dataclass
class Recording:
    """A bag's joined signals: arrays over the rows, and what was wrong with the file (or None)."""

    time: np.ndarray  # [s]
    supply_pressure: np.ndarray  # [Pa] gauge
    main_valve: np.ndarray  # [m], NaN where the bag has none
    pilot_poppet: np.ndarray  # [m], NaN where the bag has none
    inlet_flow: np.ndarray  # [m^3/s], NaN where not required and absent
    problem: str = None
    inlet_flow_time: np.ndarray = None  # [s] time of each row's flow sample (None: the row's)
    tank_pressure: np.ndarray = None  # [Pa] gauge, NaN where the bag has none
    relief_flow: np.ndarray = None  # [m^3/s], NaN where the bag has none

    def valve_pressure(self):
        """Return the supply pressure above the tank [Pa]: p_s - p_t where p_t is known."""
        if self.tank_pressure is None:
            return self.supply_pressure
        return np.where(
            np.isnan(self.tank_pressure),
            self.supply_pressure,
            self.supply_pressure - self.tank_pressure,
        )


def read_recording(path, signal_map=None, required=BAG_REQUIRED):
    """
    Read a bag (an MCAP file or a rosbag2 bag folder) as a Recording.

    Roles not required are NaN where the bag lacks them.

    Raises InputFileError if a required signal is missing or unreadable.
    """
    from mcap_ros2.decoder import DecoderFactory

    signal_map = signal_map or SignalMap()
    optional = [role.name for role in ROLES if role.name not in required]
    decoders, joiner, rows = DecoderFactory(), Joiner(required, optional), []
    wanted = {signal_map.topics[role] for role in (*required, *optional)}
    found, problems = set(), []
    for file in bag_files(path):  # a file, or the files of a bag folder in order
        reader, extractors = BagReader(file), {}
        for channel, schema, message in reader.messages(wanted):
            if channel.id not in extractors:
                extractors[channel.id] = _extractor(file, channel, schema, signal_map, decoders)
            extractor, decode = extractors[channel.id]
            try:
                decoded = decode(message.data)
            except Exception as error:  # the decoder raises anything, struct.error to IndexError
                raise InputFileError(
                    f'{file}: a message on {channel.topic} does not decode: {error}'
                ) from error
            for role, time_ns, value in extractor.samples(decoded, message.log_time):
                rows.extend(joiner.add(role, time_ns, value))
        found.update(channel.topic for channel in reader.channels.values())
        problems += [reader.problem] if reader.problem else []
        problems += [
            f'{file}: {extractor.non_finite} value(s) on {extractor.topic} are not finite '
            '(inf or NaN) and were left out'
            for extractor, _ in extractors.values()
            if extractor.non_finite
        ]
    rows.extend(joiner.finish())
    for role in required:
        if signal_map.topics[role] not in found and reader.problem:
            raise InputFileError(
                f'{reader.problem}. Nothing of {signal_map.topics[role]} ({role}) could be read '
                'before the end: no chunk of the file is complete'
            )
        if signal_map.topics[role] not in found:
            raise InputFileError(
                f'{path} has no topic {signal_map.topics[role]} ({role}); its topics: '
                f'{", ".join(sorted(found)) or "none"} '
                f'(map another with --topic-{role.replace("_", "-")})'
            )
    if not rows:
        raise InputFileError(
            f'{path}: no sample has all of {", ".join(required)} (nothing to analyse)'
        )
    column = {
        role: np.array([np.nan if row.get(role) is None else row[role] for _, row in rows])
        for role in (
            'supply_pressure', 'main_valve', 'pilot_poppet', 'inlet_flow', 'tank_pressure',
            'relief_flow',
        )
    }
    flow_times = [row['times'].get('inlet_flow', time_ns) for time_ns, row in rows]
    return Recording(
        np.array([seconds(time_ns) for time_ns, _ in rows]),
        problem='; '.join(problems) or None,
        inlet_flow_time=np.array([seconds(time_ns) for time_ns in flow_times]),
        **column,
    )


def _extractor(path, channel, schema, signal_map, decoders):
    """(Extractor, decode function) for a channel."""
    decode = decoders.decoder_for(channel.message_encoding, schema)
    if decode is None:
        raise InputFileError(
            f'{path}: topic {channel.topic} is not a ROS 2 message with a ros2msg schema '
            f"(encoding '{channel.message_encoding}')"
        )
    return Extractor(
        channel.topic, schema.name, signal_map.roles_of(channel.topic), signal_map
    ), decode


def analyse(recording, threshold=1e-6, merge_time=0.05):
    """Step records of every step in a Recording (step_analysis.StepAnalysis over its rows)."""
    analysis, records = StepAnalysis(threshold, merge_time), []
    flow_time = recording.time if recording.inlet_flow_time is None else recording.inlet_flow_time
    for row in zip(
        recording.time,
        recording.supply_pressure,
        recording.main_valve,
        recording.inlet_flow,
        flow_time,
        np.full(len(recording.time), np.nan)
        if recording.tank_pressure is None else recording.tank_pressure,
    ):
        records += analysis.add(*row)
    return records + analysis.finish()


def analyse_step(recording, t_step, direction):
    """Step record of a step at a given time t_step [s] (no detection)."""
    measures = step_measures(
        recording.time, recording.valve_pressure(), recording.main_valve, t_step, direction
    )
    if recording.tank_pressure is not None:
        measures.details.update(tank_details(recording.time, recording.tank_pressure, t_step))
    return step_record(t_step, None, direction, measures)


def plot_steps(path, recording, records, first_number=1):
    """
    Draw Figure 5 of each step.

    The figure goes to path itself for one step, and to path with _step<k> before
    the suffix for several. Titles give the step's number in the recording (the
    first record's is first_number) and its time from the first sample (a bag's
    own time axis is often the epoch).
    """
    from pathlib import Path

    from valve_sim.analysis.plotting import plot_step_response

    path, written = Path(path), []
    pressure = recording.valve_pressure()
    above_tank = recording.tank_pressure is not None and bool(
        np.any(np.isfinite(recording.tank_pressure))
    )
    for k, record in enumerate(records, start=first_number):
        target = path if len(records) == 1 else path.with_name(f'{path.stem}_step{k}{path.suffix}')
        t_step = record['t_step']
        shown = (recording.time >= t_step - PLOT_LEAD) & (recording.time <= t_step + WINDOW)
        flows = {
            name: flow[shown]
            for name, flow in (('inlet', recording.inlet_flow), ('relief', recording.relief_flow))
            if flow is not None and np.any(np.isfinite(flow[shown]))
        }
        plot_step_response(
            target,
            recording.time[shown] - t_step + PLOT_LEAD,
            pressure[shown],
            recording.main_valve[shown],
            recording.pilot_poppet[shown],
            PLOT_LEAD,
            record,
            title=(
                f'Recorded step {k}, {t_step - recording.time[0]:.4f} s after the first '
                f'sample, shown at {PLOT_LEAD:g} s'
            ),
            flows=flows if 'relief' in flows else None,
            pressure='p_s - p_t' if above_tank else 'p_s',
        )
        written.append(target)
    return written


def print_steps(records, recording, first_number=1, paper=False):
    """
    Print each step's measures as a table (valve_sim.commands.simulate.print_table).

    Steps are numbered in the recording from first_number. paper: show the paper's
    values beside them, for the paper's own step on the reference valve only (the demo;
    a bag does not say which valve it recorded).
    """
    from valve_sim.commands.simulate import print_table

    for k, record in enumerate(records, start=first_number):
        direction = 'up' if record['direction'] > 0 else 'down'
        print(
            f'step {k}: {direction} at t = {record["t_step"]:.6f} s '
            f'({record["t_step"] - recording.time[0]:.4f} s after the first sample)'
        )
        print_table(
            StepMeasures({name: record[name] for name in MEASURE_NAMES}, record['reasons']),
            paper=paper,
        )
        details = record['details']
        if details.get('t_step_bracket'):
            t_a, t_b = details['t_step_bracket']
            how = (
                'located from the supply pressure'
                if details['t_step_from'] == 'supply_pressure'
                else 'not visible in the supply pressure: dated at its last sample before '
                'the new flow'
            )
            print(
                f'  step time: between flow samples {t_a - recording.time[0]:.4f} s and '
                f'{t_b - recording.time[0]:.4f} s ({(t_b - t_a) * 1e3:.3g} ms apart), {how}; '
                f'uncertainty +-{details["t_step_uncertainty_s"] * 1e3:.2g} ms'
            )
        if record['details'].get('T_s_from') == 'supply_pressure':
            print(
                '  T_s_ms: from the supply pressure (main valve not recorded): the time after '
                'which |p_s - p_inf| stays below 5 % of p_1 - p_inf'
            )
        if 'note' in record['details']:
            print(f'  note: {record["details"]["note"]}')
        if 'tank_pressure_pa' in details:
            print(
                '  pressure: the supply above the tank; tank at '
                f'{details["tank_pressure_pa"]:.6g} Pa (gauge) at the step'
            )
        relief = flows_around(recording, record['t_step'])
        if relief:
            print(
                '  flows [L/min] before the step / at the end of its window: inlet '
                f'{relief[0] * 6e4:.4g} / {relief[1] * 6e4:.4g}, relief (to the tank) '
                f'{relief[2] * 6e4:.4g} / {relief[3] * 6e4:.4g}'
            )


def flows_around(recording, t_step):
    """
    (inlet, inlet, relief, relief) flow [m^3/s] just before t_step and at the window's end.

    None where the recording has no relief flow there.
    """
    if recording.relief_flow is None:
        return None
    before = max(int(np.searchsorted(recording.time, t_step, side='right')) - 1, 0)
    end = max(int(np.searchsorted(recording.time, t_step + WINDOW, side='right')) - 1, 0)
    values = (
        recording.inlet_flow[before], recording.inlet_flow[end],
        recording.relief_flow[before], recording.relief_flow[end],
    )
    return values if np.all(np.isfinite(values[2:])) else None


def add_signal_arguments(parser):
    """--namespace, --topic-*, --joint-*, --ambient-pressure and --clock: where the signals are."""
    parser.add_argument('--namespace', metavar='NS',
                        help="namespace the valve's topics were recorded under (e.g. /rig1); "
                        'relative --topic-* names resolve in it (default: the one namespace '
                        "with valve_node's topics in the bag, else /)")
    for role in ROLES:
        option = role.name.replace('_', '-')
        parser.add_argument(f'--topic-{option}', metavar='TOPIC',
                            help=f'topic of the {role.meaning} (default {role.topic} in the '
                            'namespace)')
        if role.joint:
            parser.add_argument(f'--joint-{option}', metavar='NAME', default=role.joint,
                                help=f'JointState joint name of the {role.meaning} '
                                f'(default {role.joint})')
    ambient = SETTING_SPECS['ambient_pressure']
    parser.add_argument('--ambient-pressure', default=STANDARD_ATMOSPHERE, metavar='PA',
                        type=number('a pressure', 'Pa', ambient.minimum, ambient.maximum),
                        help='subtracted from the recorded pressure to get gauge pressure; 0 '
                        f'for a gauge sensor (default {STANDARD_ATMOSPHERE:g})')
    parser.add_argument('--clock', choices=CLOCKS, default='header',
                        help='time of a sample: its header stamp, or its receive time (needed '
                        'for Float64 topics)')


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


def signal_map_from(args, command='analyse'):
    """
    Build the SignalMap of --namespace, --topic-*, --joint-*, --ambient-pressure and --clock.

    Without --namespace, the roles left at their default topics look in the namespace
    detect_namespace() finds in the bag (said on stderr when it is not the root); sets
    args.namespace to the namespace used ('' for the root).
    """
    options = vars(args)
    given = {role.name: options[f'topic_{role.name}'] for role in ROLES}
    if args.namespace is None:
        args.namespace = detect_namespace(args.bag, [r for r, topic in given.items() if not topic])
        if args.namespace:
            print(f'valve-sim {command}: the valve topics of {args.bag} are under '
                  f'{args.namespace}: analysing those (--namespace chooses)', file=sys.stderr)
    namespace = namespace_name(args.namespace)
    args.namespace = namespace
    topics = {
        role.name: resolved(given[role.name] or role.topic, namespace) for role in ROLES
    }
    joints = {role.name: options[f'joint_{role.name}'] for role in ROLES if role.joint}
    return SignalMap(topics, joints, args.ambient_pressure, args.clock)


def resolved(topic, namespace):
    """Return topic resolved in namespace ('' the root): relative names go below it."""
    return topic if topic.startswith('/') else f'{namespace}/{topic}'


def bag_topics(path):
    """{topic: type name} of every channel of a bag (an MCAP file or a bag folder)."""
    topics = {}
    for file in bag_files(path):
        reader = BagReader(file)
        for _ in reader.messages(topics=()):  # records every channel, yields no message
            pass
        topics.update(
            {c.topic: reader.schemas[c.schema_id].name for c in reader.channels.values()
             if c.schema_id in reader.schemas}
        )
    return topics


def detect_namespace(path, roles):
    """
    Return the namespace of valve_node's topics in a bag, for roles left at their defaults.

    '' when the root has them (or roles is empty, or no namespace has them); the one
    namespace whose supply_pressure (FluidPressure) and applied_inlet_flow (JointState)
    the bag holds; raises InputFileError naming them when several namespaces do.
    """
    if not roles:
        return ''
    topics = bag_topics(path)
    namespaces = sorted(
        topic[: -len('/' + ROLE['supply_pressure'].topic)]
        for topic, type_name in topics.items()
        if topic.endswith('/' + ROLE['supply_pressure'].topic)
        and type_name == FLUID_PRESSURE
        and topics.get(topic.rsplit('/', 1)[0] + '/' + ROLE['inlet_flow'].topic) == JOINT_STATE
    )
    if not namespaces or '' in namespaces:
        return ''
    if len(namespaces) > 1:
        raise InputFileError(
            f"{path} holds valve_node's topics under {len(namespaces)} namespaces: "
            f'{", ".join(namespaces)}; choose one with --namespace'
        )
    return namespaces[0]


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
        from valve_sim.commands.characteristic import print_marks

        print(
            f'{args.bag}: static characteristic, cracking and reseat from {marks.basis}'
            + (' (pressures: the supply above the recorded tank pressure)' if above_tank else '')
        )
        print_marks(marks)
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
        print_steps(records, recording)
    else:
        print(
            f'no inlet-flow step in {args.bag} ({len(recording.time)} samples, '
            f'{recording.time[-1] - recording.time[0]:.3f} s)'
        )
    return 0
