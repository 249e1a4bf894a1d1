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

"""Benchmark a lockstep scenario's speed over real time, and where its time goes (issue 29)."""

# The summary above is also this script's --help description.
#
#     flock /tmp/valve_sim_bench.lock python bench/bench_scenario.py [--repeats 3] [--json F]
#         [--baseline DIR]
#     python bench/bench_scenario.py --every-input [--repeats 3] [--json F] [--baseline DIR]
#
# In one run, on a ROS domain of its own (localhost only), each --repeats times, in turn,
# each in a fresh process:
#
# - model: valve_node's RealTimeModel advanced tick by tick (1 ms, 100 RK4 steps) in
#   this process, the paper step's flows: the model alone;
# - round trip: a bare rclpy node (on valve_node's executor) that answers each /clock
#   with the two messages that end a tick (applied_inlet_flow, relief_flow), driven by
#   valve_sim.ros.lockstep.Lockstep: the DDS round trip and the driver, the floor any
#   lockstep run here has;
# - lockstep: valve_node alone in lockstep (every tick topic published at 1 kHz, no
#   recorder), one tick per /clock: model + publishing + round trip;
# - lockstep_jumps: the same with /clock stepping STEP_TICKS ticks at once
#   (valve_sim.ros.clock_jumps): a round trip per STEP_TICKS ticks;
# - scenario_one_tick: `scenario run` of scenarios/paper_step.yaml, analyser_node
#   recording every topic, one tick per /clock (as with --wait-topic);
# - scenario: the same as `scenario run` did it before issue 46, STEP_TICKS ticks per /clock;
# - scenario_k100, scenario_ramp_k100: scenario and scenario_ramp with
#   MAX_TICKS_PER_CLOCK ticks per /clock (issue 46: the default now): the speed-up of fewer round
#   trips, side by side, and whether the tick topics stay bit for bit the same (each
#   run's digest of its bag's tick topics, messages with their log and publish times).
#
# Each reports its real-time factor (model time per wall time of the stepping), its
# wall time per tick, and the CPU time per tick of each process over the stepping
# (the driver or runner, valve_node or the bare node, analyser_node), read from
# /proc: on two cores these, not the wall times alone, say where a tick goes.
# --baseline DIR runs every kind also with the valve_sim of another checkout (e.g.
# `git archive main | tar -x -C DIR`), its processes on PYTHONPATH=DIR, alternating
# with this checkout's in the same run: before and after side by side under the same
# load (the two jump kinds only where the checkout has clock jumps; a checkout without
# them runs `scenario` one tick per /clock). The load average at start and end is
# printed: the machine is shared.

import argparse
import json
import os
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time


REPO = Path(__file__).resolve().parent.parent
SCENARIO = REPO / 'scenarios' / 'paper_step.yaml'
KINDS = ('model', 'round_trip', 'lockstep', 'lockstep_jumps', 'scenario_one_tick',
         'scenario', 'scenario_ramp', 'scenario_k100', 'scenario_ramp_k100')
STEP_TICKS = 10  # ticks per /clock of the kinds scenario*, lockstep_jumps: compared with 100
SAME_TICKS = (('scenario', 'scenario_k100'), ('scenario_ramp', 'scenario_ramp_k100'))
# scenario_ramp: the paper step's run with inputs that change every tick (a ramp 5 -> 20
# L/min over 0.5 s from 0.25 s, then a sine on top until the end): stamped inputs let it
# step STEP_TICKS ticks per /clock as the step does (issue 42)
RAMP_SCENARIO = (
    'scenario: paper_ramp\nduration: 1.3\ninputs:\n  inlet_flow:\n    initial: 5 L/min\n'
    '    changes:\n      - {at: 0.25, ramp: 20 L/min, over: 0.5}\n'
    '      - {at: 0.75, sine: {amplitude: 3 L/min, frequency: 8}}\nexpect:\n  - no_alarm: {}\n')
# --every-input: 60 s of model time with every input kind the format has (issue 46): the
# inlet flow's step, ramp, sine and a recorded series (CSV), a tank pressure profile
# (step, ramp, sine) and events setting a fault, a sensor and a live parameter; with
# --baseline DIR the other checkout's command alternately (run in DIR: -m puts it first), and
# each run's digest of its bag's tick topics and inputs (lockstep_messages) compared
EVERY_INPUT = """scenario: every_input_60s
description: every input kind for 60 s
duration: 60
inputs:
  inlet_flow:
    initial: 5 L/min
    changes:
      - {at: 5, step: 15 L/min}
      - {at: 15, ramp: 25 L/min, over: 10}
      - {at: 30, sine: {amplitude: 3 L/min, frequency: 2}, over: 10}
      - {at: 42, series: {csv: flow.csv, time: t, value: q, unit: L/min}}
  tank_pressure:
    initial: 0 bar
    changes:
      - {at: 10, step: 2 bar}
      - {at: 20, ramp: 5 bar, over: 10}
      - {at: 50, sine: {amplitude: 1 bar, frequency: 1}, over: 5}
events:
  - {t: 35, set: {fault.seat_leakage_diameter: 0.0002}}
  - {t: 45, set: {sensor.supply_pressure.bias: 100000}}
  - {t: 55, set: {supply_pressure_limit: 25 MPa}}
expect:
  - no_alarm: {}
"""
# the command's progress lines that end each phase, in order (ros.scenario_runner)
PHASES = (('start-up: nodes, discovery', 'scenario: running '),
          ('stepping', 'scenario: waiting for analyser_node to record'),
          ('analyser drain', 'scenario: stopping both nodes'),
          ('stop, analysis, reports', None))
JUMP_KINDS = ('lockstep_jumps', 'scenario_one_tick', 'scenario_k100',
              'scenario_ramp_k100')  # need valve_sim.ros.clock_jumps
CLOCK_TICKS = os.sysconf('SC_CLK_TCK')
ATTEMPTS = 5  # runs of a kind that abort before the bench gives up
BARE_RESPONDER = (
    'import rclpy\n'
    'from rclpy.qos import QoSProfile, ReliabilityPolicy\n'
    'from rosgraph_msgs.msg import Clock\n'
    'from sensor_msgs.msg import JointState\n'
    'rclpy.init()\n'
    "node = rclpy.create_node('bare_responder')\n"
    'qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)\n'
    "publishers = [node.create_publisher(JointState, topic, qos)  # as a tick's handshake\n"
    "              for topic in ('applied_inlet_flow', 'relief_flow')]  # and its last topic\n"
    'message = JointState(velocity=[0.0])\n'
    'def answer(clock):\n'
    '    message.header.stamp = clock.clock\n'
    '    for publisher in publishers:\n'
    '        publisher.publish(message)\n'
    "node.create_subscription(Clock, '/clock', answer, 10)\n"
    'from valve_sim.ros.spinning import DEFAULT_EXECUTOR, EXECUTORS\n'
    'executor = EXECUTORS[DEFAULT_EXECUTOR]()  # the executor valve_node spins\n'
    'executor.add_node(node)\n'
    'try:\n'
    '    while rclpy.ok():\n'
    '        executor.spin_once(timeout_sec=0.1)\n'
    'except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):\n'
    '    pass\n'
)


def cpu_seconds():
    """CPU time [s] of this process and of each child, by name: {name: user + system}."""
    times = {}
    for pid in filter(str.isdigit, os.listdir('/proc')):
        try:
            stat = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
            command = Path(f'/proc/{pid}/cmdline').read_bytes().decode(errors='replace')
        except OSError:
            continue  # ended meanwhile
        if int(pid) == os.getpid():
            name = 'driver'
        elif int(stat[1]) == os.getpid():
            name = next((n for n in ('bare_responder', 'valve_node', 'analyser_node')
                         if n in command), command[:30])
        else:
            continue
        times[name] = (int(stat[11]) + int(stat[12])) / CLOCK_TICKS
    return times


def cpu_used(before, after):
    return {name: after[name] - before.get(name, 0.0) for name in after}


def model_alone(scenario, folder):
    """Advance valve_node's RealTimeModel tick by tick with the scenario's flows."""
    from valve_sim.core.parameters import load_parameters
    from valve_sim.core.realtime_model import RealTimeModel

    loaded = load_parameters()
    params, settings = loaded.params, loaded.settings
    flows = scenario.inputs['inlet_flow'].sample(scenario.tick_times())
    model = RealTimeModel(params, settings['step_size'], flows[0])
    model.trial(params, settings['step_size'], flows[0])  # kernels loaded, as the node does
    model.start(0)
    cpu, started = cpu_seconds(), time.perf_counter()
    for tick in range(1, scenario.ticks + 1):
        model.advance_to(tick * scenario.period_ns, flows[tick - 1], 10 ** 12)
    return time.perf_counter() - started, cpu_used(cpu, cpu_seconds())


def lockstep_run(scenario, folder, name, ticks_per_clock=1):
    """Drive one node process (valve_node or the bare node) on /clock for the scenario's ticks."""
    import rclpy
    from valve_sim.ros import node_command
    from valve_sim.ros.lockstep import Lockstep
    from valve_sim.ros.node_processes import NodeProcesses

    if name == 'valve_node':
        from valve_sim.ros.lockstep import lockstep_parameters

        command = node_command('valve_node', parameters={
            **lockstep_parameters(),
            'initial_inlet_flow': repr(scenario.inputs['inlet_flow'].initial)})
    else:
        command = [sys.executable, '-c', BARE_RESPONDER, '--ros-args', '-p',
                   'use_sim_time:=true']
    processes = NodeProcesses(folder, {name: command})
    context = rclpy.Context()
    rclpy.init(context=context)
    driver = None
    try:
        driver = Lockstep(context, processes=processes)
        driver.spin_until(lambda: driver.clock.get_subscription_count() > 0
                          and all(s.get_publisher_count() > 0 for s in driver.subscriptions),
                          f'{name} connected', 180.0)
        if name == 'valve_node':
            driver.set_flow(scenario.inputs['inlet_flow'].initial)
        driver.start(period_ns=scenario.period_ns)
        cpu, started = cpu_seconds(), time.perf_counter()
        for done in range(0, scenario.ticks, ticks_per_clock):
            if ticks_per_clock == 1:
                driver.tick()  # as a checkout without clock jumps can
            else:
                driver.tick(min(ticks_per_clock, scenario.ticks - done))
        return time.perf_counter() - started, cpu_used(cpu, cpu_seconds())
    finally:
        if driver is not None:
            driver.close()
        context.try_shutdown()
        processes.stop()


def scenario_run(scenario, folder, **options):
    """
    Run the scenario as `valve-sim scenario run` does; its stepping's wall [s] and CPU.

    Also the digest of its bag's tick topics (lockstep_messages), where the checkout has it.
    """
    import hashlib

    from valve_sim.ros import scenario_runner
    from valve_sim.ros.scenario_runner import run_scenario

    cpu = {}

    def progress(text):  # the runner's own lines mark the stepping's start and end
        if text.startswith('running '):
            cpu['start'] = cpu_seconds()
        elif text.startswith('waiting for analyser_node to record'):
            cpu['end'] = cpu_seconds()

    record = run_scenario(scenario, folder, progress=progress, **options)
    assert record.passed, [check.name for check in record.checks if not check.passed]
    digest = None
    if hasattr(scenario_runner, 'lockstep_messages'):
        from valve_sim.recording.valve_topics import TICK_TOPICS

        messages = scenario_runner.lockstep_messages(record.bag, TICK_TOPICS)
        digest = hashlib.sha256(repr(sorted(messages.items())).encode()).hexdigest()
    return record.wall_s, cpu_used(cpu['start'], cpu['end']), digest


def measure(kind, folder):
    """Measure one kind in this process; print {wall_s, cpu_s} as one JSON line."""
    from valve_sim.analysis.scenarios.bench_scenario import load_scenario

    scenario = load_scenario(SCENARIO)
    folder.mkdir(parents=True, exist_ok=True)
    digest = None
    options = {'ticks_per_clock': STEP_TICKS}
    if kind.endswith('_k100'):
        from valve_sim.ros.clock_jumps import MAX_TICKS_PER_CLOCK

        options['ticks_per_clock'] = MAX_TICKS_PER_CLOCK
    if kind.startswith('scenario_ramp'):
        (folder / 'ramp.yaml').write_text(RAMP_SCENARIO)
        scenario = load_scenario(folder / 'ramp.yaml')
    if kind == 'model':
        wall, cpu = model_alone(scenario, folder)
    elif kind in ('scenario', 'scenario_ramp', 'scenario_k100', 'scenario_ramp_k100'):
        wall, cpu, digest = scenario_run(scenario, folder, **options)
    elif kind == 'scenario_one_tick':
        wall, cpu, digest = scenario_run(scenario, folder, ticks_per_clock=1)
    elif kind == 'lockstep_jumps':
        wall, cpu = lockstep_run(scenario, folder, 'valve_node', STEP_TICKS)
    else:
        wall, cpu = lockstep_run(scenario, folder,
                                 'bare_responder' if kind == 'round_trip' else 'valve_node')
    print(json.dumps({'wall_s': wall, 'cpu_s': cpu, 'ticks': scenario.ticks,
                      'duration_s': scenario.duration, 'digest': digest}))


def run_kind(kind, folder, checkout, aborted):
    """
    Measure kind in a fresh process that imports valve_sim from checkout.

    A run that aborts (a checkout whose inputs can race /clock) is noted in aborted
    and run again, up to ATTEMPTS times.
    """
    environment = dict(os.environ, PYTHONPATH=str(checkout))
    for attempt in range(ATTEMPTS):
        completed = subprocess.run(
            [sys.executable, __file__, '--measure', kind, '--folder', str(folder / str(attempt))],
            env=environment, capture_output=True, text=True, cwd=checkout)
        if completed.returncode == 0:
            return json.loads(completed.stdout.strip().splitlines()[-1])
        aborted.append(f'{kind}: ' + (completed.stderr.strip().splitlines() or ['?'])[-1])
        print(f'  {kind} aborted: {aborted[-1]}', flush=True)
    raise RuntimeError(f'{kind} aborted {ATTEMPTS} times')


def summary(runs):
    """Median wall and CPU per tick of the runs of one kind."""
    ticks, duration = runs[0]['ticks'], runs[0]['duration_s']
    wall = statistics.median(run['wall_s'] for run in runs)
    names = sorted({name for run in runs for name in run['cpu_s']})
    return {'runs': len(runs), 'median_wall_s': wall,
            'walls_s': [run['wall_s'] for run in runs],
            'digests': sorted({run.get('digest') for run in runs} - {None}),
            'real_time_factor': duration / wall, 'per_tick_ms': wall / ticks * 1e3,
            'cpu_per_tick_ms': {name: statistics.median(run['cpu_s'].get(name, 0.0)
                                                        for run in runs) / ticks * 1e3
                                for name in names}}


def kinds_of(checkout):
    """Return the kinds a checkout can run: the jump kinds only with ros.clock_jumps."""
    jumps = (Path(checkout) / 'valve_sim' / 'ros' / 'clock_jumps.py').exists()
    return [kind for kind in KINDS if jumps or kind not in JUMP_KINDS]


def split(results):
    """
    Where a scenario's tick goes [ms of wall], from the kinds' wall times.

    One tick per /clock (as with --wait-topic), and, where the checkout has clock jumps,
    as `scenario` steps: STEP_TICKS ticks per /clock, so a round trip's share
    of a tick is a round trip over STEP_TICKS (the runner's splits at events add a
    few round trips more); and what inputs that change every tick add to a step's run.
    """
    tick = {kind: result['per_tick_ms'] for kind, result in results.items()}
    splits = {}
    if {'scenario', 'scenario_ramp'} <= set(tick):  # what inputs changing every tick cost
        splits['a ramp and a sine against a step, both as scenario run steps'] = {
            'step': tick['scenario'], 'ramp_and_sine': tick['scenario_ramp'],
            'stamped_inputs': tick['scenario_ramp'] - tick['scenario']}
    if not {'model', 'round_trip', 'lockstep', 'scenario'} <= set(tick):
        return splits
    one_tick = tick.get('scenario_one_tick', tick['scenario'])
    splits['one tick per /clock'] = {
        'model': tick['model'],
        'round_trip_floor': tick['round_trip'],
        'valve_node_publishing_and_executor': tick['lockstep'] - tick['round_trip']
        - tick['model'],
        'analyser_and_runner': one_tick - tick['lockstep'],
    }
    if 'lockstep_jumps' in tick:
        round_trip = tick['round_trip'] / STEP_TICKS
        splits[f'{STEP_TICKS} ticks per /clock (scenario)'] = {
            'model': tick['model'],
            'round_trip_share': round_trip,
            'valve_node_publishing_and_executor': tick['lockstep_jumps'] - round_trip
            - tick['model'],
            'analyser_and_runner': tick['scenario'] - tick['lockstep_jumps'],
        }
    return splits


def report(label, results):
    print(f'{label}:')
    for kind in filter(results.__contains__, KINDS):
        result = results[kind]
        cpu = ', '.join(f'{name} {value:.3f}'
                        for name, value in result['cpu_per_tick_ms'].items())
        print(f'  {kind:<17} {result["real_time_factor"]:7.2f}x real time, '
              f'{result["per_tick_ms"]:.3f} ms a tick; CPU ms a tick: {cpu}')
    for kind, other in SAME_TICKS:
        if kind in results and other in results:
            same = results[kind]['digests'] == results[other]['digests'] and len(
                results[kind]['digests']) == 1
            gain = results[other]['real_time_factor'] / results[kind]['real_time_factor']
            print(f'  {kind} vs {other}: tick topics bit for bit the same in every run: '
                  f'{same}; speed-up {gain:.2f}x')
    for stepping, parts in results['split_per_tick_ms'].items():
        print(f'  where a scenario tick goes, {stepping} [ms of wall]: ' + ', '.join(
            f'{name} {value:.3f}' for name, value in parts.items()))


def every_input(folder, repeats, checkouts=None):
    """
    `valve-sim scenario run` of EVERY_INPUT as a command, repeats times; print the figures.

    Each run: the whole command's wall (real-time factor), the stepping's (report.json
    run.wall_s), the wall of each phase (from the command's progress lines, read as
    they come) and the CPU of the command with its nodes (getrusage of the children).
    checkouts: {label: checkout folder or None (this one)}, run alternately in each
    repeat (another's on PYTHONPATH); returns {label: [runs]}.
    """
    import math

    folder.mkdir(parents=True, exist_ok=True)
    (folder / 'flow.csv').write_text('t,q\n' + ''.join(
        f'{k / 10:.1f},{10 + 4 * math.sin(k / 10) + 2 * (k % 10 < 5):.4f}\n'
        for k in range(81)))  # 8 s at 10 Hz, a sine and a square wave [L/min]
    path = folder / 'every_input.yaml'
    path.write_text(EVERY_INPUT)
    checkouts = checkouts or {'this checkout': None}
    runs = {label: [] for label in checkouts}
    for repeat in range(repeats):
        for label, checkout in checkouts.items():
            out = folder / f'run_{repeat}_{label.replace(" ", "_")}'
            runs[label].append(every_input_run(path, out, checkout))
            run = runs[label][-1]
            print(f'every input, run {repeat + 1}, {label}: whole command '
                  f'{run["whole_s"]:.1f} s = {60 / run["whole_s"]:.2f}x real time (target >= 3); '
                  f'stepping {run["stepping_s"]:.1f} s = {60 / run["stepping_s"]:.2f}x (target '
                  f'>= 4); CPU of the command and its nodes {run["cpu_s"]:.1f} s '
                  f'({run["cpu_s"] / run["whole_s"]:.2f} cores); tick topics and inputs '
                  f'{run["digest"]}; phases: ' + ', '.join(
                      f'{name} {value:.1f} s' for name, value in run['phases_s'].items())
                  + (f'; FAILED: {run["error"]}' if run['error'] else ''), flush=True)
    digests = {run['digest'] for label in runs for run in runs[label]}
    count = sum(map(len, runs.values()))
    print(f"every input: the bags' tick topics and inputs alike in all {count} runs: "
          f'{len(digests) == 1}', flush=True)
    return runs


def every_input_run(path, out, checkout=None):
    """One `scenario run` of path into out (checkout: another valve_sim on PYTHONPATH)."""
    import resource

    environment = dict(os.environ, **({'PYTHONPATH': str(checkout)} if checkout else {}))
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.monotonic()
    command = subprocess.Popen(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'scenario', 'run', str(path),
         '--out', str(out)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=environment, cwd=checkout or REPO)  # -m puts the folder it runs in first
    marks, phase, lines = {}, 0, []
    for line in command.stdout:
        lines.append(line)
        while PHASES[phase][1] and line.startswith(PHASES[phase][1]):
            marks[PHASES[phase][0]] = time.monotonic() - started
            phase += 1
    whole = time.monotonic() - started
    failed = command.wait() != 0  # then the error, and the phases up to it
    marks[PHASES[-1][0]] = whole
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    ends = [marks[name] for name, _ in PHASES if name in marks]
    reports = list(out.rglob('report.json'))
    stepping = (json.loads(reports[0].read_text())['run']['wall_s'] if reports else
                marks.get(PHASES[1][0], whole) - marks.get(PHASES[0][0], 0.0))
    bags = sorted(out.glob('*.mcap'))
    return {'whole_s': whole, 'stepping_s': stepping,
            'error': lines[-1].strip() if failed else None,
            'digest': digest(bags[0]) if bags else None,
            'cpu_s': after.ru_utime + after.ru_stime - cpu.ru_utime - cpu.ru_stime,
            'phases_s': dict(zip([name for name, _ in PHASES if name in marks],
                                 [ends[0]] + [b - a for a, b in zip(ends, ends[1:])]))}


def digest(bag):
    """Return a short digest of a bag's tick topics and inputs (lockstep_messages), times too."""
    import hashlib

    from valve_sim.ros.scenario_runner import lockstep_messages

    messages = sorted(lockstep_messages(bag).items())
    return hashlib.sha256(repr(messages).encode()).hexdigest()[:16]


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3, help='runs of each kind')
    parser.add_argument('--kinds', nargs='+', choices=KINDS, help='only these kinds')
    parser.add_argument('--json', type=Path, help='also write the figures as JSON')
    parser.add_argument('--baseline', type=Path,
                        help='another checkout of valve_sim, measured alongside (before/after)')
    parser.add_argument('--every-input', action='store_true',
                        help='instead: `scenario run` of 60 s with every input kind, '
                        '--repeats times (whole command and stepping against real time)')
    parser.add_argument('--measure', choices=KINDS, help=argparse.SUPPRESS)
    parser.add_argument('--folder', type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        return measure(args.measure, args.folder)
    from valve_sim.ros.isolation import claim_domain

    claim_domain(keep_existing=False)  # the measuring processes inherit the domain
    if args.every_input:
        print(f'load average at start: {os.getloadavg()}', flush=True)
        checkouts = {'this checkout': None}
        if args.baseline:
            checkouts['baseline'] = args.baseline.resolve()
        with tempfile.TemporaryDirectory() as temporary:
            runs = every_input(Path(temporary), args.repeats, checkouts)
        for label, values in runs.items():
            done = [run for run in values if not run['error']]
            if done:
                print(f'every input, {label}, median of {len(done)}: whole command '
                      f'{60 / statistics.median(r["whole_s"] for r in done):.2f}x, stepping '
                      f'{60 / statistics.median(r["stepping_s"] for r in done):.2f}x real time')
        print(f'load average at end: {os.getloadavg()}')
        if args.json:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(runs, indent=2) + '\n')
        return None
    checkouts = {'this checkout': REPO}
    if args.baseline:
        checkouts['baseline'] = args.baseline.resolve()
    print(f'load average at start: {os.getloadavg()}', flush=True)
    aborted = {label: [] for label in checkouts}
    runs = {label: {kind: [] for kind in kinds_of(checkout)
                    if not args.kinds or kind in args.kinds}
            for label, checkout in checkouts.items()}
    with tempfile.TemporaryDirectory() as temporary:
        for repeat in range(args.repeats):
            for label, checkout in checkouts.items():
                for kind in runs[label]:
                    folder = Path(temporary) / str(repeat) / label.replace(' ', '_') / kind
                    runs[label][kind].append(run_kind(kind, folder, checkout, aborted[label]))
                print(f'run {repeat + 1}, {label}: ' + ', '.join(
                    f'{kind} {values[-1]["wall_s"]:.3f} s'
                    for kind, values in runs[label].items()), flush=True)
    results = {}
    for label in checkouts:
        results[label] = {kind: summary(values) for kind, values in runs[label].items()}
        results[label]['split_per_tick_ms'] = split(results[label])
        results[label]['aborted_runs'] = aborted[label]
    results['load_average_end'] = os.getloadavg()
    scenario = next(iter(runs['this checkout'].values()))[0]
    print(f'{scenario["duration_s"]:g} s of model time, {scenario["ticks"]} ticks '
          f'(scenarios/{SCENARIO.name}), median of {args.repeats}:')
    for label, checkout in checkouts.items():
        report(f'{label} ({checkout})', results[label])
        print(f'  runs that aborted and were run again: {len(aborted[label])}')
    print(f'load average at end: {results["load_average_end"]}')
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2) + '\n')


if __name__ == '__main__':
    main()
