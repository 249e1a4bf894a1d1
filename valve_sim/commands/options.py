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
The options several commands take, declared once (OPTIONS), and the argument types.

A command adds the shared options it takes by name, add_options(parser, '--params', ...),
and declares its own beside them with parser.add_argument, so that its add_arguments()
still lists its options in the order of its --help. Changes adapt a shared option to
the command: add_options(parser, '--json', help='print the marks as JSON').

This module imports only the standard library and valve_sim's light modules, and so do
the commands' module levels, so that `valve-sim CMD --help` is quick: the model
(numba, scipy) loads when a command runs, as in load_from_arguments.

Longer than 400 lines on purpose: it is the one module a subcommand may import besides
the library (the layering rule, test/lint/test_layering.py), so every option, argument
type and argument reader two subcommands share lives here, in one place to look.
"""

from argparse import ArgumentTypeError
from contextlib import contextmanager
from dataclasses import replace
from datetime import datetime, timezone
import math
from pathlib import Path
import signal
import sys
import threading

from valve_sim.analysis.steps.signals import CLOCKS, ROLES, SignalMap
from valve_sim.analysis.studies.backend import BYTES_PER_WORKER, CORES, MAX_RUNS, WORKERS_PER_CORE
from valve_sim.analysis.studies.cases import DEFAULT_PROTOCOL, PROTOCOLS
from valve_sim.core.catalogue import CATALOGUE
from valve_sim.core.errors import ParameterError
from valve_sim.core.flow_step import LITRE_PER_MINUTE
from valve_sim.core.input_files import PARAMETER_FILE, size_text
from valve_sim.core.parameters import (
    check_value,
    load_parameters,
    SETTING_SPECS,
    SPECS,
    STANDARD_ATMOSPHERE,
)


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


def number(kind, unit, low, high, low_open=False, integer=False):
    """
    Return an argparse type: finite values (integers if integer) in [low, high] or (low, high].

    Every numeric option of valve-sim is parsed by one of these (or by flow_value,
    pressure_value), so a NaN, an infinity or an absurd value is a usage error that
    names the range, never a run with nonsense results. The type's bounds (its
    attribute bounds) are added to the option's --help by the CLI's help formatter.
    """
    shown = '{:,}' if integer else '{:g}'
    interval = (
        f'{"(" if low_open else "["}{shown.format(low)}, {shown.format(high)}]'
        f'{(" " + unit) if unit else ""}'
    )

    def parse(text):
        try:
            value = int(text) if integer else float(text)
        except ValueError:
            raise ArgumentTypeError(f'not {kind}: {text!r}') from None
        inside = low < value <= high if low_open else low <= value <= high
        if not (math.isfinite(value) and inside):
            raise ArgumentTypeError(f'{kind} must be in {interval}, got {text!r}')
        return value

    parse.__name__ = kind  # argparse names the type in its messages
    parse.bounds = f'in {interval}'
    return parse


def flow_value(text):
    """Parse a volume flow from '8.3e-5', '8.3e-5m^3/s' or '5L/min' -> m^3/s (argparse type)."""
    units = {'L/min': LITRE_PER_MINUTE, 'l/min': LITRE_PER_MINUTE, 'm^3/s': 1.0, 'm3/s': 1.0}
    value = quantity(text, units, 'flow', '5L/min or 8.33e-5')
    if not 0.0 <= value <= MAX_FLOW:
        raise ArgumentTypeError(f'flow must be {flow_value.bounds}, got {text!r}')
    return value


STEP_SIZE = SETTING_SPECS['step_size']  # [s] its limits bound --step-size
# The largest flow any option takes: the largest max_inlet_flow a valve may be given.
MAX_FLOW = SPECS['max_inlet_flow'].maximum  # [m^3/s]
flow_value.bounds = f'in [0, {MAX_FLOW:g}] m^3/s'


def pressure_value(text):
    """Parse a pressure from '7e6', '7e6Pa', '7MPa' or '70bar' -> Pa (argparse type)."""
    units = {'MPa': 1e6, 'kPa': 1e3, 'bar': 1e5, 'Pa': 1.0}
    value = quantity(text, units, 'pressure', '7MPa or 7e6')
    if not math.isfinite(value) or value <= 0.0:
        raise ArgumentTypeError(f'pressure must be finite and > 0, got {text!r}')
    return value


pressure_value.bounds = 'finite, > 0 Pa'


def gauge_pressure_value(text):
    """Parse a gauge pressure, 0 or below too: '1e6', '-0.5bar', '1MPa' -> Pa (argparse type)."""
    units = {'MPa': 1e6, 'kPa': 1e3, 'bar': 1e5, 'Pa': 1.0}
    value = quantity(text, units, 'pressure', '1MPa or 1e6')
    if not math.isfinite(value):
        raise ArgumentTypeError(f'pressure must be finite, got {text!r}')
    return value


gauge_pressure_value.bounds = 'finite Pa (gauge), not below vacuum, below burst_pressure'


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
    if getattr(CATALOGUE.get(name.strip()), 'kind', None) == 'string':  # fault_schedule
        return name.strip(), value.strip()
    try:
        return name.strip(), int(value) if value.strip().isdigit() else float(value)
    except ValueError:
        raise ArgumentTypeError(f'value of {name.strip()!r} is not a number: {value!r}') from None


OPTIONS = {
    # The model: a parameter file, single parameters, the preset; see load_from_arguments.
    '--params': {
        'metavar': 'FILE.yaml',
        'help': 'ROS 2 parameter file overlaid on config/reference.yaml '
        f'(e.g. config/table2.yaml; a regular file, {PARAMETER_FILE.limits()})',
    },
    '--set': {
        'type': assignment,
        'action': 'append',
        'default': [],
        'metavar': 'NAME=VALUE',
        'help': 'override one parameter (ROS name or paper symbol, SI units; simulate also '
        'takes fault.* and sensor.* settings, true/false for switches); repeatable',
    },
    '--preset-pressure': {
        'type': pressure_value,
        'metavar': 'P',
        'help': 'main-valve cracking pressure (gauge, e.g. 7MPa): sets pilot_spring_preload '
        'like the adjusting screw, after --params and --set (also preset_pressure in a file '
        'or --set)',
    },
    '--tank-pressure': {
        'type': gauge_pressure_value,
        'metavar': 'P',
        'help': "the tank's (return line's) pressure, gauge (e.g. 1MPa; default: tank_pressure "
        'of the parameter file or --set, 0: the tank at ambient); the valve cracks that much '
        'higher (docs/model.md, "Back pressure")',
    },
    '--step-size': {
        'type': number('a step size', 's', STEP_SIZE.minimum, STEP_SIZE.maximum),
        'metavar': 'S',
        'help': 'RK4 step [s] (default: step_size of the parameter file, 1e-5)',
    },
    # What a command writes; most commands say in their own words what (help=...).
    '--out': {'metavar': 'DIR', 'required': True, 'help': 'output folder (created if missing)'},
    '--json': {'action': 'store_true'},
    '--plot': {
        'metavar': 'FILE.png',
        'help': 'draw the figure to FILE.png (an existing folder: a file of the default name '
        'in it)',
    },
    '--mcap': {'metavar': 'FILE.mcap'},
    '--bag-folder': {
        'action': 'store_true',
        'help': 'with --mcap: write a rosbag2 bag folder there instead (metadata.yaml + '
        '<folder name>_0.mcap; the folder must not exist yet)',
    },
    '--start-time': {
        'type': start_time,
        'metavar': 'UTC',
        'help': 'with --mcap: wall-clock time of model time 0, ISO 8601 (e.g. '
        '2026-11-29T12:00:00Z; default: now, to the millisecond)',
    },
    '--seed': {'type': number('a seed', '', 0, 2**63 - 1, integer=True), 'default': 0,
               'metavar': 'N'},
}


def add_options(parser, *flags, **changes):
    """
    Add the shared options flags to parser, in that order, as OPTIONS declares them.

    changes (help=..., default=...) replace keywords of the declaration: give them with
    one flag, to say what the option means to this command.
    """
    for flag in flags:
        parser.add_argument(flag, **{**OPTIONS[flag], **changes})


def load_from_arguments(args, with_injection=False):
    """
    Return the LoadedParameters of the model's options, --params to --step-size.

    The sections of --params that apply are those rcl applies to valve_node in the
    command's --namespace, if it has one (else the root namespace). --step-size
    overrides settings["step_size"], --tank-pressure settings["tank_pressure"]; fault
    and sensor settings are its injection with with_injection (else they are refused).
    A preset pressure (--preset-pressure, else preset_pressure of --set or the file) sets
    the pilot spring preload last.
    """
    from valve_sim.core.steady_state import with_preset_pressure

    namespace = namespace_name(getattr(args, 'namespace', None))
    loaded = load_parameters(args.params, dict(args.set), namespace, with_injection)
    params, settings = loaded.params, loaded.settings
    preset = settings.pop('preset_pressure', None)
    preset = getattr(args, 'preset_pressure', None) or preset
    if preset is not None:
        params = with_preset_pressure(params, check_value('preset_pressure', preset))
    if getattr(args, 'tank_pressure', None) is not None:
        settings['tank_pressure'] = args.tank_pressure
    check_tank_pressure(settings['tank_pressure'], params, settings)
    if settings['tank_pressure'] and not hasattr(args, 'tank_pressure'):
        print(
            f"valve-sim: tank_pressure = {settings['tank_pressure']:g} Pa of the parameters is "
            'not used here: this command takes the valve with the tank at ambient '
            '(simulate and operating-point take --tank-pressure)',
            file=sys.stderr,
        )
    if getattr(args, 'step_size', None):
        settings['step_size'] = args.step_size
    if not STEP_SIZE.minimum <= settings['step_size'] <= STEP_SIZE.maximum:
        raise ParameterError(
            f'step size {settings["step_size"]:g} s is outside '
            f'[{STEP_SIZE.minimum:g}, {STEP_SIZE.maximum:g}] s'
        )
    return replace(loaded, params=params, settings=settings)


def check_tank_pressure(pressure, params, settings):
    """Raise ParameterError unless pressure [Pa, gauge] is a valid tank pressure for the valve."""
    from valve_sim.core.limits import tank_pressure_problem

    problem = tank_pressure_problem(
        pressure, params['burst_pressure'], settings['ambient_pressure']
    )
    if problem:
        raise ParameterError(problem)


def plot_path(value, default_name):
    """
    Return the file --plot names: value itself, or default_name inside it if it is a folder.

    A name without a suffix gets '.png', as matplotlib would add it.
    """
    path = Path(value)
    if path.is_dir():
        return path / default_name
    return path if path.suffix else path.with_name(path.name + '.png')


def namespace_name(namespace):
    """'/rig1', 'rig1/' or '/' -> '/rig1', '/rig1' or '' (the root namespace), for --namespace."""
    stripped = (namespace or '').strip().strip('/')
    return '/' + stripped if stripped else ''


def check_bag_arguments(args):
    """Refuse --bag-folder and --start-time without --mcap (ParameterError)."""
    if (args.bag_folder or args.start_time is not None) and not args.mcap:
        raise ParameterError('--bag-folder and --start-time need --mcap')


# The studies' options (study, tolerance, sensitivity, optimise): the protocol and the runner.

def add_study_arguments(parser, samples_help):
    """Add the options tolerance and sensitivity share: the model's, --out, --samples, --seed."""
    add_options(parser, '--params', '--set', '--preset-pressure', '--out')
    parser.add_argument('--samples', type=number('a sample count', '', 1, 10**12, integer=True),
                        default=256, metavar='N',
                        help=f'{samples_help}; at most {MAX_RUNS:,} runs in all')
    add_options(parser, '--seed', help='seed of the sampler (default 0)')
    add_options(parser, '--step-size')


def add_protocol_arguments(parser):
    """--protocol and its short form --frozen-preload."""
    parser.add_argument('--protocol', choices=PROTOCOLS, default=DEFAULT_PROTOCOL,
                        help='held-preset: preload re-solved per case, the preset held '
                        '(default, the paper); frozen-preload: the preload of the parameter '
                        'file in every case')
    parser.add_argument('--frozen-preload', dest='protocol', action='store_const',
                        const='frozen-preload', help='same as --protocol frozen-preload')


def add_runner_arguments(parser):
    """--scheduler, --workers, --batch-size and --resume."""
    parser.add_argument('--scheduler', metavar='tcp://HOST:PORT',
                        help='address of a running Dask scheduler (default: a local cluster '
                        'on this machine)')
    parser.add_argument('--workers', type=number('a worker count', '', 1, 10**6, integer=True),
                        default=CORES, metavar='N',
                        help='worker processes of the local cluster (default: all cores; at '
                        f'most {WORKERS_PER_CORE} per core, {size_text(BYTES_PER_WORKER)} '
                        'of memory each)')
    parser.add_argument('--batch-size', metavar='N',
                        type=number('a batch size', '', 1, MAX_RUNS, integer=True),
                        help='runs per task (default: about 8 tasks per worker, at most 64 runs)')
    parser.add_argument('--resume', action='store_true',
                        help='keep the runs already in DIR/results.jsonl and compute only the '
                        'missing ones')
    parser.add_argument('--dashboard', nargs='?', const='127.0.0.1:0', metavar='HOST:PORT',
                        type=dashboard_address,
                        help="serve Dask's dashboard of the local cluster and print its address "
                        '(default 127.0.0.1:0: this machine only, a free port; 0.0.0.0:PORT '
                        'shows it to the network). Without it the local cluster has none, and '
                        'every part of it listens on 127.0.0.1 only')


def dashboard_address(text):
    """Parse --dashboard's HOST:PORT, PORT in [0, 65535] (argparse type)."""
    host, colon, port = text.strip().rpartition(':')
    if not (colon and host and port.isdigit() and int(port) <= 65535):
        raise ArgumentTypeError(f'must be HOST:PORT with a PORT in [0, 65535], got {text!r}')
    return f'{host}:{int(port)}'


dashboard_address.bounds = 'HOST:PORT, PORT in [0, 65535]'


# Where the signals of a recorded bag are (analyse, calibrate --bag).

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


def signal_map_from(args, command='analyse'):
    """
    Build the SignalMap of --namespace, --topic-*, --joint-*, --ambient-pressure and --clock.

    Without --namespace, the roles left at their default topics look in the namespace
    detect_namespace() finds in the bag (said on stderr when it is not the root); sets
    args.namespace to the namespace used ('' for the root).
    """
    from valve_sim.recording.signal_reader import detect_namespace

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


@contextmanager
def ctrl_c_stops():
    """
    Within the block, Ctrl-C asks a long computation to stop instead of raising at once.

    Yields should_stop() for the library (e.g. analysis.calibration.fit.calibrate), true once
    Ctrl-C (SIGINT) was pressed; the computation then ends with what it has. A second
    Ctrl-C raises KeyboardInterrupt as usual (the command line: "interrupted", exit 130).
    Outside the main thread, where Python takes no signals, should_stop() stays false.
    """
    pressed = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield pressed.is_set
        return
    previous = signal.getsignal(signal.SIGINT)

    def asked(signum, frame):
        pressed.set()
        signal.signal(signal.SIGINT, previous)  # the next Ctrl-C interrupts

    signal.signal(signal.SIGINT, asked)
    try:
        yield pressed.is_set
    finally:
        signal.signal(signal.SIGINT, previous)
