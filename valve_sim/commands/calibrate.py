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
Fit model parameters to the paper's step measures or to a recorded bag (valve-sim calibrate).

Target (one of): --target-measures FILE.json, the six measures with values and
tolerances (config/calibration/figure5.json: the paper's Figure 5), or --bag
BAG (an .mcap file or a rosbag2 bag folder), a recording with the topic, type and
ambient-pressure mapping of `valve-sim analyse`: the model is driven by the
recorded inlet flow and fitted to the recorded supply pressure (and the
main-valve position where recorded).
--fit names the parameters (ROS names, paper symbols, or preset_pressure), with
bounds from their specs or --bounds NAME=LO:HI. Writes into --out:
  calibrated.yaml  ROS 2 parameter file (valve_node --params-file, valve-sim --params)
  report.json, report.txt  fitted values, residuals, 95 % intervals, correlations,
                   constraints, starts, wall time
  fit.png          the recording or the targets against the calibrated model
Ctrl-C stops the fit and writes the best result so far (exit code 130).
"""

import math
from pathlib import Path
import shlex
import sys

from valve_sim.analysis.recorded_steps import analyse
from valve_sim.commands.options import (
    add_options,
    add_signal_arguments,
    flow_value,
    load_from_arguments,
    number,
    signal_map_from,
)
from valve_sim.core.flow_step import LITRE_PER_MINUTE
from valve_sim.core.input_documents import read_json
from valve_sim.core.input_files import TARGET_MEASURES
from valve_sim.core.output_files import json_text, make_folder, write_text
from valve_sim.recording.signal_reader import from_every_signal, read_recording

# The model's and the fit's modules (numba, scipy) are imported in the functions that
# run them, so that `valve-sim calibrate --help` stays quick.


def bounds_value(text):
    """'NAME=LO:HI' -> (NAME, (LO, HI)) for --bounds."""
    from argparse import ArgumentTypeError

    name, separator, span = text.partition('=')
    low, colon, high = span.partition(':')
    try:
        if not separator or not colon:
            raise ValueError
        low, high = float(low), float(high)
    except ValueError:
        raise ArgumentTypeError(f'expected NAME=LO:HI (SI units), got {text!r}') from None
    if not -math.inf < low < high < math.inf:
        raise ArgumentTypeError(f'LO and HI must be finite with LO < HI, got {text!r}')
    return name.strip(), (low, high)


def range_value(text):
    """'LO:HI' -> (LO, HI) for --main-spring-rate and --main-spring-preload (SI units)."""
    from argparse import ArgumentTypeError

    low, colon, high = text.partition(':')
    try:
        if not colon:
            raise ValueError
        low, high = float(low), float(high)
    except ValueError:
        raise ArgumentTypeError(f'expected LO:HI (SI units), got {text!r}') from None
    if not 0.0 < low < high < math.inf:
        raise ArgumentTypeError(f'LO and HI must be finite with 0 < LO < HI, got {text!r}')
    return low, high


def tie_value(text):
    """'d_v=0.98*d_s' -> ('d_v', 0.98, 'd_s') and 'd_v=d_s' -> ('d_v', 1.0, 'd_s') for --tie."""
    from argparse import ArgumentTypeError

    tied, separator, rule = text.partition('=')
    factor, star, source = rule.rpartition('*')
    try:
        if not separator or not tied.strip() or not source.strip():
            raise ValueError
        return tied.strip(), float(factor) if star else 1.0, source.strip()
    except ValueError:
        raise ArgumentTypeError(
            f'expected NAME=OTHER or NAME=FACTOR*OTHER, got {text!r}'
        ) from None


def positive_length(text):
    """Parse a length [m] > 0 for --land-margin."""
    from argparse import ArgumentTypeError

    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0.0 < value < 0.1:
        raise ArgumentTypeError(f'expected a length in m, 0 < M < 0.1, got {text!r}')
    return value


MAX_CHANGE_PERCENT = 1000.0  # [%] the largest change of a --relieves case (11 times the value)

bounds_value.bounds = 'LO, HI finite, LO < HI'
range_value.bounds = 'LO, HI finite, 0 < LO < HI'
tie_value.bounds = 'FACTOR finite, > 0'
positive_length.bounds = 'in (0, 0.1) m'

# The design rules of a main stage as real valves are built (docs/model.md), as constraints.
DESIGN_RULES = (
    ('--land-margin', positive_length, 'M', 'constraint: both throttle lands inside the guide '
     'bore, D_1, D_2 <= d_p - 2 M (M in m, e.g. 1e-3)'),
    ('--main-spring-rate', range_value, 'LO:HI',
     'constraint: main spring rate k_m within LO:HI N/m (e.g. 1e3:5e3)'),
    ('--main-spring-preload', range_value, 'LO:HI',
     'constraint: main spring preload force k_m x_0 within LO:HI N (e.g. 20:100)'),
)


def case_value(text):
    """'d_c=-20,k_p=10' -> {'d_c': -20.0, 'k_p': 10.0} for --relieves."""
    from argparse import ArgumentTypeError

    changes = {}
    for part in text.split(','):
        name, separator, percent = part.partition('=')
        try:
            if not separator:
                raise ValueError
            changes[name.strip()] = float(percent)
        except ValueError:
            raise ArgumentTypeError(
                f'expected SYMBOL=PERCENT[,SYMBOL=PERCENT...], got {text!r}'
            ) from None
        if not -100.0 < changes[name.strip()] <= MAX_CHANGE_PERCENT:
            raise ArgumentTypeError(
                f'a change must be in (-100, {MAX_CHANGE_PERCENT:g}] %, got {part.strip()!r}'
            )
    return changes


case_value.bounds = f'each PERCENT in (-100, {MAX_CHANGE_PERCENT:g}]'


def add_arguments(parser):
    add_options(parser, '--params', '--set', '--preset-pressure')
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument('--target-measures', metavar='FILE',
                        help='the six measures to fit: '
                        '{"T_1_ms": {"value": 6.7, "tolerance": 0.67}, ...} (JSON, '
                        f'{TARGET_MEASURES.limits()}), or those of a recorded step, the '
                        "paper's tolerances: an analyse --json output or a bag (.mcap or a "
                        'bag folder; --target-step)')
    target.add_argument('--bag', metavar='BAG',
                        help='a recorded step to fit: an .mcap file or a rosbag2 bag folder '
                        '(topics mapped as in analyse)')
    parser.add_argument('--target-step', type=number('a step number', '', 1, 10**6, integer=True),
                        default=1, metavar='N',
                        help='with --target-measures from a recording: its step N (default 1)')
    parser.add_argument('--fit', required=True, metavar='NAMES',
                        help='comma-separated parameters to fit (ROS names, paper symbols or '
                        'preset_pressure)')
    parser.add_argument('--bounds', type=bounds_value, action='append', default=[],
                        metavar='NAME=LO:HI',
                        help='bounds of a fitted parameter [SI] (default: its spec limits); '
                        'repeatable')
    add_options(parser, '--out')
    parser.add_argument('--max-pilot-flow', type=flow_value, metavar='Q',
                        help='constraint: pilot flow (bearings, damping orifice, rod clearance) '
                        'at most Q (e.g. 1.2L/min) at --pilot-flow-at')
    parser.add_argument('--pilot-flow-at', type=flow_value, default=5 * LITRE_PER_MINUTE,
                        metavar='Q',
                        help='inlet flow of the pilot-flow constraint (default 5L/min)')
    parser.add_argument('--table2-decays', action='store_true',
                        help="constraint: every linear mode of the paper's Table 2 case "
                        '(preset held) decays by 95 %% within the 1 s window of the measures, '
                        'at 5 and 20 L/min')
    parser.add_argument('--relieves', type=case_value, action='append', default=[],
                        metavar='SYMBOL=PERCENT[,...]',
                        help="constraint: this case of the paper's study (preset held; e.g. "
                        'd_c=-20) ends its step test relieving through the main stage; '
                        'repeatable')
    for flag, kind, metavar, text in DESIGN_RULES:
        parser.add_argument(flag, type=kind, metavar=metavar, help=text)
    parser.add_argument('--tie', type=tie_value, action='append', default=[],
                        metavar='NAME=[FACTOR*]OTHER',
                        help='NAME takes FACTOR (default 1) times the value of the fitted OTHER '
                        'at every evaluation (e.g. d_v=0.98*d_s: the pilot seat 2 %% under '
                        'the rod); repeatable')
    parser.add_argument('--study-relieves', action='store_true',
                        help="check: every case of the paper's study (preset held) opens the main "
                        'stage and ends its step test relieving through it (26 runs per start)')
    parser.add_argument('--starts', type=number('a count', '', 1, 1000, integer=True),
                        default=3, metavar='N',
                        help='optimiser starts (default 3)')
    parser.add_argument('--spread', type=number('a spread', '', 0.0, 2.0), default=0.1,
                        metavar='S',
                        help='log-normal spread of the starts after the first (default 0.1, '
                        'about 10 %%)')
    add_options(parser, '--seed', help='seed of the starts')
    parser.add_argument('--tolerance', type=number('a tolerance', '', 0.0, 1.0, low_open=True),
                        default=1e-10, metavar='TOL',
                        help='ftol = xtol = gtol of least_squares (default 1e-10)')
    add_options(parser, '--step-size')
    parser.add_argument('--quiet', action='store_true', help='no progress lines on stderr')
    add_signal_arguments(parser)


def _target(args, step_size, signal_map):
    from valve_sim.analysis.calibration.targets import MeasuresTarget, RecordingTarget
    from valve_sim.core.errors import CalibrationError

    if args.target_measures:
        path = Path(args.target_measures)
        try:
            if path.is_dir() or path.suffix == '.mcap':  # a recording: analyse it
                steps = analyse(read_recording(path, signal_map))
                return MeasuresTarget.from_step(steps, args.target_step, step_size)
            document = read_json(path, TARGET_MEASURES)
            if isinstance(document, dict) and isinstance(document.get('steps'), list):
                return MeasuresTarget.from_step(document['steps'], args.target_step, step_size)
            return MeasuresTarget.from_document(document, step_size)
        except CalibrationError as error:
            raise CalibrationError(f'{args.target_measures}: {error}') from None
    recording = read_recording(args.bag, signal_map)
    if recording.problem:
        print(f'valve-sim calibrate: warning: {recording.problem}', file=sys.stderr)
    recording, note = from_every_signal(recording, signal_map.topics)
    if note:
        print(f'valve-sim calibrate: note: {note}', file=sys.stderr)
    try:
        return RecordingTarget.from_recording(recording, step_size)
    except CalibrationError as error:
        raise CalibrationError(f'{args.bag}: {error}') from None


def run(args):
    from valve_sim.analysis.calibration.fit import calibrate, CalibrationProblem, FitSettings
    from valve_sim.analysis.calibration.parameters import (
        fit_parameters,
        fit_ties,
        step_time_parameters,
    )
    from valve_sim.analysis.calibration.report import (
        parameter_file_text,
        plot_fit,
        report_document,
        report_text,
    )
    from valve_sim.analysis.calibration.requirements import (
        CaseRelieves,
        LandsInsideBore,
        MainSpringRange,
        ModesDecay,
        PilotFlowLimit,
        StudyRelieves,
    )
    from valve_sim.analysis.calibration.verdict import judged, verdict_lines
    from valve_sim.commands.options import ctrl_c_stops
    from valve_sim.core.errors import CalibrationError

    recorded = args.bag or (args.target_measures and (
        Path(args.target_measures).is_dir() or args.target_measures.endswith('.mcap')))
    signal_map = None
    if recorded:  # the signal options apply to the bag either option names
        bag, args.bag = args.bag, args.bag or args.target_measures
        signal_map = signal_map_from(args, 'calibrate')
        args.bag = bag
    loaded = load_from_arguments(args)  # in the bag's namespace, if any
    params, settings = loaded.params, loaded.settings
    preset = args.preset_pressure or None
    if args.starts < 1 or not (0.0 <= args.spread <= 2.0) or not args.tolerance > 0.0:
        raise CalibrationError('need --starts >= 1, 0 <= --spread <= 2 and --tolerance > 0')
    step_size = settings['step_size']
    names = [name for name in args.fit.split(',') if name.strip()]
    fitted = fit_parameters(names, dict(args.bounds), params)
    ties = fit_ties(args.tie, fitted)
    target = _target(args, step_size, signal_map)
    fitted += step_time_parameters(target)  # steps between coarse flow samples: fitted too
    constraints = []
    if args.max_pilot_flow is not None:
        constraints.append(PilotFlowLimit(args.max_pilot_flow, args.pilot_flow_at))
    if args.table2_decays:
        constraints.append(ModesDecay())
    constraints += [CaseRelieves(changes) for changes in args.relieves]
    if args.land_margin is not None:
        constraints.append(LandsInsideBore(args.land_margin))
    if args.main_spring_rate or args.main_spring_preload:
        constraints.append(MainSpringRange(args.main_spring_rate or (0.0, math.inf),
                                           args.main_spring_preload or (0.0, math.inf)))
    checks = [StudyRelieves()] if args.study_relieves else []
    progress = None if args.quiet else lambda line: print(line, file=sys.stderr, flush=True)
    if progress:
        progress(
            f'calibrate: {", ".join(p.name for p in fitted)} to '
            f'{args.target_measures or args.bag}; {args.starts} start(s)'
            + (f'; preset held at {preset / 1e6:g} MPa' if preset else '')
        )
    problem = CalibrationProblem(params, fitted, target, constraints, checks, preset, ties)
    search = FitSettings(args.starts, args.spread, args.seed, args.tolerance)
    with ctrl_c_stops() as should_stop:  # Ctrl-C ends the fit with its best result so far
        result = calibrate(problem, search, progress, should_stop)
    verdict, freeing = judged(problem, result, progress)
    out = make_folder(Path(args.out))
    command = 'valve-sim calibrate ' + ' '.join(shlex.quote(a) for a in sys.argv[2:])
    write_text(out / 'calibrated.yaml', parameter_file_text(result, settings, command))
    report = report_document(result, target, args.target_measures or args.bag, command,
                             verdict, freeing)
    write_text(out / 'report.json', json_text(report) + '\n')
    text = report_text(report)
    write_text(out / 'report.txt', text)
    plot_fit(out / 'fit.png', result, target)
    print(text, end='')
    print(f'wrote {out}/calibrated.yaml, report.json, report.txt and fit.png')
    if result.interrupted:
        print('valve-sim calibrate: interrupted: wrote the best result so far', file=sys.stderr)
        return 130
    if not result.satisfied:
        print(
            'valve-sim calibrate: no start met every constraint and check '
            '(see report.txt); wrote the best one anyway',
            file=sys.stderr,
        )
        return 1
    if not verdict['explains']:
        for line in verdict_lines(report):
            print(f'valve-sim calibrate: {line}', file=sys.stderr)
        return 1
    return 0
