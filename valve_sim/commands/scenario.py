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
Bench tests as files: run a scenario on valve_node in lockstep and judge it, or check one.

`valve-sim scenario run FILE.yaml` starts valve_node and analyser_node over DDS (in
ROS_DOMAIN_ID if set, else a domain of its own; with --wait-topic in the environment's
domain as it is, where the user's other nodes run), drives /clock in steps of a few
ticks (--ticks-per-clock; tick by tick with --wait-topic) as fast as the nodes go
(--rate: at most that many times real time), feeds the scenario's inputs and events,
and judges its expectations on the recording. Into --out it writes the bag,
report.txt, report.json, scenario.png, junit.xml and both nodes' logs; it exits 0 only
if every expectation holds. Several files, or a folder (its *.yaml files in name order),
run as a suite (ros.scenario_suite): valve_node starts once, each scenario from its own
start in --out/NN_<name>/, one JUnit file with a testsuite per scenario and
summary.txt in --out; exit 0 only if every scenario passes. `valve-sim scenario check`
reads and checks files without running them. The file format: docs/scenarios.md.
"""

import argparse
import os
from pathlib import Path
import time

from valve_sim.commands.options import number
from valve_sim.core.output_files import make_folder, safe_name
from valve_sim.ros.clock_jumps import MAX_TICKS_PER_CLOCK, TICKS_PER_CLOCK


def topic_name(text):
    """Check a --wait-topic before any node starts (argparse type): rcl's rules."""
    from valve_sim.ros.topic_names import topic_problem

    problem = topic_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(f'{text!r} is not a ROS topic name: {problem}')
    return text


def progress(text):
    print(f'scenario: {text}', flush=True)


def add_arguments(parser):
    actions = parser.add_subparsers(dest='action', required=True, metavar='ACTION')
    run_parser = actions.add_parser('run', help='run a scenario and judge it',
                                    formatter_class=parser.formatter_class,
                                    description='run a scenario on valve_node in lockstep and '
                                    'judge its expectations (exit 0 only if all hold)')
    run_parser.add_argument('file', metavar='FILE.yaml', nargs='+',
                            help='the scenario (docs/scenarios.md); several, or a folder of '
                            'them: a suite on one valve_node')
    run_parser.add_argument('--out', metavar='DIR', help='folder for the bag, reports, figure '
                            'and logs (default: a new scenario_<name>_<date>-<time> folder here)')
    run_parser.add_argument('--rate', type=number('a rate', '', 0.0, 1000.0, low_open=True),
                            metavar='R',
                            help='at most R times real time (1: real time, 0.5: half speed; '
                            'default: as fast as the nodes go)')
    run_parser.add_argument('--wait-topic', action='append', default=[], metavar='TOPIC',
                            type=topic_name,
                            help='a topic another use_sim_time node (your controller) publishes '
                            'once per tick: each tick waits for its message (repeatable)')
    run_parser.add_argument('--flow-topic', metavar='TOPIC', type=topic_name,
                            help="the valve's inlet flow from the second tick on comes from your "
                            "controller's reply to each tick's state on TOPIC (a wait topic): "
                            'sensor_msgs/JointState, velocity[0] in m^3/s, stamped with the '
                            'tick it answers (docs/scenarios.md)')
    run_parser.add_argument('--ticks-per-clock', metavar='N',
                            type=number('a tick count', '', 1, MAX_TICKS_PER_CLOCK, integer=True),
                            help='tick periods per /clock message at most (default '
                            f'{TICKS_PER_CLOCK}, 1 with --wait-topic; the states are the same '
                            'either way, fewer round trips are faster)')
    run_parser.add_argument('--junit', type=Path, metavar='FILE.xml',
                            help='write the JUnit report here instead of DIR/junit.xml')
    check_parser = actions.add_parser('check', help='read and check a scenario without running',
                                      formatter_class=parser.formatter_class,
                                      description='read and check a scenario file; prints what '
                                      'it runs')
    check_parser.add_argument('file', metavar='FILE.yaml', nargs='+',
                              help='the scenario (docs/scenarios.md); several, or a folder')


def describe(scenario):
    """Return what a checked scenario runs, in a few lines."""
    from valve_sim.analysis.scenarios.bench_scenario import INPUT_UNITS

    lines = [f'scenario {scenario.name} ({scenario.path}): {scenario.duration:g} s, '
             f'{scenario.ticks + 1} ticks at {scenario.publish_rate:g} Hz']
    lines += [f'  input {name}: starts at {profile.initial:g} {INPUT_UNITS[name]}, '
              f'{len(profile.changes)} change(s)' for name, profile in scenario.inputs.items()]
    lines += [f'  event at {event.time_ns / 1e9:g} s: {event.changes}'
              for event in scenario.events]
    lines.append(f'  {len(scenario.expectations)} expectation(s)')
    return '\n'.join(lines)


def scenario_files(paths):
    """Return the scenario files of paths: each file, each folder's *.yaml and *.yml sorted."""
    from valve_sim.core.errors import InputFileError

    files = []
    for path in map(Path, paths):
        if path.is_dir():
            found = sorted(p for p in path.iterdir()
                           if p.suffix in ('.yaml', '.yml') and p.is_file())
            if not found:
                raise InputFileError(f'{path}: a folder without scenario files (*.yaml)')
            files += found
        else:
            files.append(path)
    return files


def check(files):
    """Read and check each file, print what it runs or why not; returns the exit code."""
    from valve_sim.analysis.scenarios.bench_scenario import load_scenario
    from valve_sim.core.errors import USER_ERRORS
    from valve_sim.recording.tick_bags import bag_column

    if len(files) == 1:
        print(describe(load_scenario(files[0], bag_column)))
        return 0
    broken = 0
    for file in files:
        try:
            print(describe(load_scenario(file, bag_column)))
        except USER_ERRORS as error:
            broken += 1
            print(f'scenario {file}: ERROR {error}')
    print(f'{len(files) - broken} of {len(files)} scenario files check')
    return 1 if broken else 0


def run(args):
    from valve_sim.analysis.scenarios.bench_scenario import load_scenario
    from valve_sim.recording.tick_bags import bag_column

    files = scenario_files(args.file)
    if args.action == 'check':
        return check(files)
    scenarios = [load_scenario(file, bag_column) for file in files]  # all checked first
    from valve_sim.ros.isolation import claim_domain

    stamp = time.strftime('%Y%m%d-%H%M%S')
    suite = len(args.file) > 1 or Path(args.file[0]).is_dir()
    name = 'suite' if suite else safe_name(scenarios[0].name)  # one path component
    folder = Path(args.out) if args.out else Path.cwd() / f'scenario_{name}_{stamp}'
    folder = make_folder(folder).resolve()
    if args.wait_topic or args.flow_topic:  # the user's nodes are in this domain: join them
        domain = os.environ.get('ROS_DOMAIN_ID', '0 (unset)')
    else:
        domain = claim_domain()
    what = f'a suite of {len(scenarios)} scenarios' if suite else scenarios[0].name
    progress(f'{what}: output folder {folder}; ROS_DOMAIN_ID={domain}')
    if suite:
        return run_suite(scenarios, folder, args)
    from valve_sim.ros.scenario_runner import run_and_report

    record, paths = run_and_report(scenarios[0], folder, args.rate, args.wait_topic, args.junit,
                                   progress, args.ticks_per_clock, args.flow_topic)
    print()
    print(paths['report'].read_text(), end='')
    for path in (record.bag, *paths.values()):
        progress(f'wrote {path}')
    return 0 if record.passed else 1


def run_suite(scenarios, folder, args):
    """Run scenarios as a suite on one valve_node; print the summary; returns the exit code."""
    from valve_sim.ros import scenario_suite

    records, paths, starts = scenario_suite.run_suite(
        scenarios, folder, args.rate, args.wait_topic, args.junit, progress,
        args.ticks_per_clock, args.flow_topic)
    print()
    print(paths['summary'].read_text(), end='')
    progress(f'valve_node started {starts} time(s) for {len(records)} scenarios')
    for path in paths.values():
        progress(f'wrote {path}')
    return 0 if all(record.passed for record in records) else 1
