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
Attack valve_node and the tools with every class of hostile input (issue 25); report.

    python bench/attack.py [--json out/attack.json] [--only STEP]   (bench/attack.sh runs it)

Starts valve_node (wall clock, and one on /clock) and applies each class:
  1 files      every hostile file of test/hostile_inputs.py set live as fault_schedule,
               and given to every reader of the command line (--params, --faults,
               --target-measures, a bag folder's metadata.yaml, --resume)
  2 clock      /clock negative and past 2^31 s; a jump back, then an overpressure
  3 roll-back  each kind of parameter changed, then rolled back by an overpressure
  4 wire       a resolution of 1e-320, a stuck sensor beyond its range, inf samples
  5 recordings a bit flip in a chunk length, a sparse hole, a full disk, a rogue type
  6 options    meaningless numbers, huge --samples and --workers, --plot DIR, a link
  7 outputs    (issue 43) --junit and fmu --out through links to FIFOs, node logs and
               optimise's subfolders planted as links, hostile scenario names
  8 checks     windows and bounds outside the run, a window without samples, a scenario
               of 25,000 changes over 3,600 s checked in time linear in the file
  9 budgets    a 50 MB results line under ulimit -v, NaN, ±-1%, bad wait topics, a
               missing extra, a tank pressure flipping every tick (valve_node's log)
The suite's modules each class uses must import (--check-imports, a test runs it).
Each attack reports whether everything survived it (the node alive and publishing,
its largest gap between published stamps; a command's one-line refusal and its time)
and the table goes to stdout and --json. Exit code 0 only if everything survived.
"""

import argparse
import json
import os
from pathlib import Path
import signal
import stat
import subprocess
import sys
import tempfile
import time

from common import isolated_environment, REPO, write_figures


# The suite's probe and hostile inputs, and the test modules the classes take their cases from.
TEST_FOLDERS = ('test', 'test/ros', 'test/commands', 'test/recording')
sys.path[:0] = [str(REPO / folder) for folder in TEST_FOLDERS]
CLASS_MODULES = {  # attack step: the suite's modules it imports
    'live': ('test_hostile_node', 'hostile_inputs', 'valve_harness'),
    'readers': ('hostile_inputs',),
    'sim': ('test_hostile_node', 'valve_harness'),
    'wire': ('hostile_inputs',),
    'recordings': ('hostile_inputs', 'test_hostile_options', 'test_recovery'),
    'rogue_type': ('test_analyser',),
    'options': ('test_hostile_options',),
    'outputs': (),
    'checks': ('test_hostile_scenarios',),
    'budgets': ('valve_harness',),
}

NS_PER_S = 1_000_000_000
WINDOW_SAMPLES = 200  # published samples per window, idle or under attack (1 kHz: 0.2 s)
IDLE_WINDOWS = 3  # idle windows after each schedule, each as long as its window
FREEZE_RATIO = 5.0  # the largest gap under attack / the worst idle window's: above, a freeze
# (the freezes found took seconds or for ever; the checker process reading a file competes
# for the cores, so gaps under attack run above idle ones by that alone: 1.9x measured)


class Report:
    """The attacks' outcomes: (class, attack, survived, detail) rows."""

    def __init__(self):
        self.rows = []

    def add(self, klass, attack, survived, detail):
        self.rows.append({'class': klass, 'attack': attack, 'survived': bool(survived),
                          'detail': detail})
        mark = 'survived' if survived else 'FAILED'
        print(f'{klass:<11} {attack[:44]:<44} {mark:<9} {detail}', flush=True)

    def table(self, figures):
        failed = [row for row in self.rows if not row['survived']]
        return (f'{len(self.rows) - len(failed)} of {len(self.rows)} attacks survived in '
                f'{figures["seconds"]:.0f} s' + ''.join(
                    f'\n  FAILED: {row["class"]}: {row["attack"]}: {row["detail"]}'
                    for row in failed))


def valve_sim(*arguments, timeout=120, cwd=None):
    """Run `valve-sim ARGUMENTS`; return (exit code, stderr's last line, seconds)."""
    started = time.monotonic()
    try:
        result = subprocess.run(
            [sys.executable, '-m', 'valve_sim.commands.cli', *map(str, arguments)],
            capture_output=True, text=True, timeout=timeout, cwd=cwd or REPO,
        )
    except subprocess.TimeoutExpired:
        return None, f'no answer in {timeout} s', timeout
    lines = result.stderr.strip().splitlines()
    return result.returncode, lines[-1] if lines else '', time.monotonic() - started


def refusal(report, klass, attack, *arguments, also='', within=60):
    """
    Run `valve-sim ARGUMENTS`; report whether it refused in one line of its own.

    The line must name also, and come within `within` seconds.
    """
    code, line, seconds = valve_sim(*arguments)
    refused = code in (1, 2) and 'Traceback' not in line and also in line and seconds < within
    report.add(klass, attack, refused, f'{seconds:.2f} s: {line[-70:]}')


def attack_live_schedules(report, context, folder, only=None):
    """
    Class 1, live: each hostile schedule set on a running node (only: names holding it).

    A freeze (the tick blocked while a file is read) is told from the machine's own
    jitter side by side: after each schedule, IDLE_WINDOWS idle windows of as many
    published samples as its window had (from setting it to WINDOW_SAMPLES after it was
    refused). The node survives a schedule if, beyond refusing it, its largest gap
    between published stamps stays within FREEZE_RATIO times the worst idle window's of
    this run (a wall-clock bound would measure the machine's load, not the node).
    """
    from test_hostile_node import BAD_SCHEDULES, largest_stamp_gap, schedule_in_effect
    from hostile_inputs import make_file
    from valve_harness import running_valve

    rows = []
    with running_valve(context, folder / 'valve_node.log', namespace='/attack') as (
        process, probe
    ):
        for number, (kind, content) in enumerate(BAD_SCHEDULES.items()):
            if only and only not in kind:
                continue
            path = folder / f'schedule_{number}.yaml'
            make_file(path, content)
            start, started = probe.count(), time.monotonic()
            result = probe.set_parameters(fault_schedule=str(path))[0]
            in_effect = schedule_in_effect(probe)
            seconds = time.monotonic() - started
            probe.wait_for_new_samples(WINDOW_SAMPLES)
            gap_ms, samples = largest_stamp_gap(probe, start) / 1e6, probe.count() - start
            idle_ms = 0.0
            for _ in range(IDLE_WINDOWS):
                idle = probe.count()
                probe.wait_for_new_samples(samples)
                idle_ms = max(idle_ms, largest_stamp_gap(probe, idle) / 1e6)
            rows.append((kind, process.poll() is None and in_effect == '', result.successful,
                         seconds, gap_ms, idle_ms))
            print(f'  measured {kind[:40]}: largest gap {gap_ms:.1f} ms, idle {idle_ms:.1f} ms',
                  flush=True)
    worst_idle_ms = max((row[5] for row in rows), default=0.0)
    for kind, refused, accepted_first, seconds, gap_ms, idle_ms in rows:
        report.add(
            '1 files', f'fault_schedule: {kind}',
            refused and gap_ms <= FREEZE_RATIO * worst_idle_ms,
            f'{"refused once read" if accepted_first else "refused at once"} in '
            f'{seconds:.2f} s; largest gap {gap_ms:.1f} ms = '
            f'{gap_ms / worst_idle_ms:.2f} x idle worst {worst_idle_ms:.1f} ms '
            f'(its idle windows: {idle_ms:.1f} ms)',
        )


def attack_readers(report, folder):
    """Class 1, offline: every reader of the command line, each hostile input."""
    from hostile_inputs import FILES, JSON_TEXTS, make_file, YAML_TEXTS

    for kind, content in {**FILES, **YAML_TEXTS}.items():
        for option in ('--params', '--faults'):
            path = folder / f'reader_{option[2:]}_{len(os.listdir(folder))}.yaml'
            make_file(path, content)
            refusal(report, '1 files', f'simulate {option}: {kind}',
                    'simulate', option, path, '--end-time', '0.3')
        bag = folder / f'bag_{len(os.listdir(folder))}'
        bag.mkdir()
        make_file(bag / 'metadata.yaml', content)
        refusal(report, '1 files', f'analyse BAG/metadata.yaml: {kind}', 'analyse', bag)
    for kind, content in {**FILES, **JSON_TEXTS}.items():
        path = folder / f'target_{len(os.listdir(folder))}.json'
        make_file(path, content)
        refusal(report, '1 files', f'calibrate --target-measures: {kind}', 'calibrate',
                '--target-measures', path, '--fit', 'd_c', '--out', folder / 'calib')


def attack_clock_and_roll_backs(report, context, folder):
    """Classes 2 and 3 on a node driven by /clock."""
    import test_hostile_node as hostile
    from valve_harness import running_valve

    defaults = hostile.reference_values()
    with running_valve(context, folder / 'valve_node_sim.log', namespace='/attack_sim',
                       use_sim_time=True) as (process, probe):
        probe.start_clock(hostile.START_S * NS_PER_S, hostile.PERIOD_NS)
        for sec, nanosec in ((-5, 0), (2**31 - 1, 4_000_000_000)):
            probe.restore(defaults, hostile.FLOW)
            stamp_ns, expected_ns = hostile.bad_clock_then_good(probe, sec, nanosec)
            report.add('2 clock', f'/clock sec={sec} nanosec={nanosec}',
                       process.poll() is None and stamp_ns == expected_ns,
                       'ignored and counted; ticking on the good clock')
        for kind, change in hostile.ROLL_BACK_CASES.items():
            probe.restore(defaults, hostile.FLOW)
            before = hostile.change_and_overpressure(probe, **change)
            agree = probe.get_parameters(*before) == before
            report.add('3 roll-back', kind, agree and process.poll() is None,
                       'declared parameters as before the change' if agree else
                       f'declared {probe.get_parameters(*before)} != {before}')
        probe.restore(defaults, hostile.FLOW)
        jumps, diagnostics = hostile.preset_change_jump_back_overpressure(probe)
        kept = probe.get_parameters('preset_pressure')['preset_pressure']
        report.add('2 clock', 'jump back 2000 s, then an overpressure',
                   int(diagnostics['clock_jumps_back']) == jumps + 1 and abs(kept - 6.5e6) < 1.0,
                   'the 1000 s old preset change kept (new time base)')
        hostile.take_flow(probe, hostile.FLOW)


def attack_wire(report, folder):
    """Class 4."""
    from hostile_inputs import bag_with_inf_pressure
    from valve_sim.core.sensors import default_settings, SensorStage

    refusal(report, '4 wire', 'resolution 1e-320', 'simulate', '--set',
            'sensor.supply_pressure.resolution=1e-320', also='resolution')
    stage = SensorStage({**default_settings(), 'sensor.supply_pressure.range_max': 1e7,
                         'sensor.supply_pressure.stuck': True,
                         'sensor.supply_pressure.stuck_at': 1e9})
    reading = stage.read(0, [7e6] * 4)[0]
    report.add('4 wire', 'stuck_at 1e9 Pa, range_max 1e7 Pa', reading == 1e7,
               f'published {reading:g} Pa')
    bag = folder / 'inf.mcap'
    bag_with_inf_pressure(bag)
    result = subprocess.run([sys.executable, '-m', 'valve_sim.commands.cli', 'analyse', str(bag),
                             '--json'], capture_output=True, text=True, cwd=REPO, timeout=120)
    try:
        json.loads(result.stdout, parse_constant=lambda name: 1 / 0)
        strict = True
    except (ValueError, ZeroDivisionError):
        strict = False
    report.add('4 wire', 'analyse --json of a bag with inf samples', strict,
               'strict JSON, null with reasons' if strict else result.stdout[-70:])


def attack_recordings(report, folder):
    """Class 5."""
    from hostile_inputs import make_sparse_mcap
    from test_hostile_options import FULL_DISK
    from test_recovery import flipped_chunk_length, log_times

    path = folder / 'flipped.mcap'
    _, everything = flipped_chunk_length(path, bit=40)
    code, line, seconds = valve_sim('repair', path, '-o', folder / 'flipped.repaired.mcap')
    kept = len(log_times(folder / 'flipped.repaired.mcap')) if code == 0 else 0
    report.add('5 recordings', 'bit flip in a chunk length (footer kept)',
               kept == len(everything), f'repair kept {kept} of {len(everything)}')
    hole = folder / 'hole.mcap'
    make_sparse_mcap(hole)
    refusal(report, '5 recordings', 'MCAP magic and a 2 GiB sparse hole', 'analyse', hole,
            also='corrupt at byte 8', within=10)
    measures = folder / 'bag.measures.json'
    result = subprocess.run([sys.executable, '-c', FULL_DISK, str(measures)], cwd=REPO,
                            capture_output=True, text=True, timeout=120)
    try:
        steps = len(json.loads(measures.read_text())['steps'])
    except (OSError, ValueError, KeyError):
        steps = None
    report.add('5 recordings', 'disk full during a measures append',
               'failed:' in result.stdout and steps == 3, f'file valid, {steps} steps kept')


def attack_rogue_type(report, context, folder):
    """Class 5: a rogue publisher of another type on supply_pressure, recorded by the analyser."""
    import rclpy
    from sensor_msgs.msg import FluidPressure
    from test_analyser import ROGUE_PUBLISHER

    analyser = subprocess.Popen(
        [sys.executable, '-m', 'valve_sim.ros.analyser_node', '--ros-args', '-p',
         f'output_dir:={folder / "rogue"}'],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=REPO,
    )
    rogue = subprocess.Popen([sys.executable, '-c', ROGUE_PUBLISHER])
    node = rclpy.create_node('attack_pressure', context=context)
    publisher = node.create_publisher(FluidPressure, 'supply_pressure', 10)
    for _ in range(3000):
        publisher.publish(FluidPressure(fluid_pressure=7e6))
        time.sleep(0.002)
    analyser.send_signal(signal.SIGINT)
    analyser.wait(timeout=60)
    rogue.kill()
    rogue.wait()
    node.destroy_node()
    from valve_sim.recording.bag import BagReader

    bag = next((folder / 'rogue').glob('*.mcap'))
    recorded = sum(1 for _ in BagReader(bag).messages({'/supply_pressure'}))
    report.add('5 recordings', 'a rogue type on /supply_pressure', recorded > 1000,
               f'{recorded} of 3000 pressure messages recorded')


def attack_options(report, folder):
    """Class 6."""
    from test_hostile_options import OPTIMISE, OPTIONS

    for arguments, option, values in OPTIONS:
        for value in values:
            code, line, seconds = valve_sim(*arguments, f'{option}={value}', cwd=folder)
            report.add('6 options', f'{arguments[0]} {option}={value}', code == 2,
                       f'{seconds:.2f} s: {line[-60:]}')
    for arguments in (['tolerance', '--vary', 'd_c=±2%', '--samples', '1000000000'],
                      ['sensitivity', '--samples', '1073741824'],
                      ['tolerance', '--vary', 'd_c=±2%', '--workers', '100000'],
                      [*OPTIMISE[:-2], '--samples', '524288'],
                      [*OPTIMISE[:-2], '--population', '10000', '--generations', '11']):
        refusal(report, '6 options', f'{arguments[0]} {" ".join(arguments[-2:])}', *arguments,
                '--out', folder / 'study', also='memory')
    plots = folder / 'plots'
    plots.mkdir()
    code, line, _ = valve_sim('simulate', '--end-time', '0.4', '--step-time', '0.1',
                              '--plot', plots)
    report.add('6 options', 'simulate --plot EXISTING_DIR',
               code == 0 and (plots / 'figure5.png').exists(), 'wrote DIR/figure5.png')
    bag = folder / 'cut.mcap'
    bag.write_bytes((REPO / 'bags/reference_step.mcap').read_bytes()[:600_000])
    victim = folder / 'victim.txt'
    victim.write_text('precious')
    (folder / 'cut.repaired.mcap').symlink_to(victim)
    code, line, _ = valve_sim('repair', bag)
    report.add('6 options', 'repair with a planted link at BAG.repaired.mcap',
               code == 0 and victim.read_text() == 'precious', 'the link replaced, not followed')


def attack_outputs(report, folder):
    """Class 7: outputs only where the user said, only into regular files."""
    import xml.etree.ElementTree as ElementTree

    fifo, victim = folder / 'pipe', folder / 'victim.txt'
    os.mkfifo(fifo)
    victim.write_text('precious')
    (folder / 'valve.fmu').symlink_to(fifo)
    code, line, seconds = valve_sim('fmu', '--out', folder / 'valve.fmu')
    report.add('7 outputs', 'fmu --out LINK to a FIFO with no reader',
               code == 1 and 'no reader' in line and stat.S_ISFIFO(os.stat(fifo).st_mode),
               f'{seconds:.2f} s: {line[-60:]}')
    out = folder / 'run'
    out.mkdir()
    for name in ('valve_node.log', 'analyser_node.log', 'report.txt'):
        (out / name).symlink_to(victim)
    scenario = folder / 'named.yaml'
    scenario.write_text('scenario: "bell\\a esc\\e[31m"\nduration: 0.5\ninputs: {inlet_flow: '
                        '{initial: 5 L/min, changes: [{at: 0.2, step: 20 L/min}]}}\n'
                        'expect: [{no_alarm: {}}]\n')
    reader = subprocess.Popen(['cat', str(fifo)], stdout=subprocess.PIPE)
    code, line, seconds = valve_sim('scenario', 'run', scenario, '--out', out,
                                    '--junit', folder / 'valve.fmu', timeout=300)
    junit = reader.communicate(timeout=60)[0]
    try:
        ElementTree.fromstring(junit)
        formed = True
    except ElementTree.ParseError:
        formed = False
    report.add('7 outputs', 'scenario run: node logs planted as links, --junit to a FIFO',
               code in (0, 1) and victim.read_text() == 'precious' and formed
               and stat.S_ISFIFO(os.stat(fifo).st_mode),
               f'{seconds:.1f} s: victim kept, JUnit {"well-formed" if formed else "BROKEN"} '
               'through the FIFO')
    work = folder / 'work'
    work.mkdir()
    escape = '../' * 2 + 'x\\0y'  # out of the working folder, a NUL
    scenario.write_text(scenario.read_text().replace('bell\\a esc\\e[31m', escape))
    code, line, seconds = valve_sim('scenario', 'run', scenario, cwd=work, timeout=300)
    made = [path.name for path in work.iterdir()]
    report.add('7 outputs', 'scenario: a name up two folders, a NUL, no --out',
               code in (0, 1) and len(made) == 1 and not (folder / 'x').exists(),
               f'{seconds:.1f} s: wrote {made}')
    elsewhere = folder / 'elsewhere'
    for name in ('params', 'evaluations'):
        (elsewhere / name).mkdir(parents=True)
        (folder / 'optimise' / name).parent.mkdir(exist_ok=True)
        (folder / 'optimise' / name).symlink_to(elsewhere / name)
    code, line, seconds = valve_sim(
        'optimise', '--design', 'd_c=±5%', '--minimise', 'P_1_percent', '--tolerance',
        'd_c=±5um', '--out', folder / 'optimise', '--population', '4', '--generations', '1',
        '--samples', '2', '--confirm-samples', '2', '--workers', '1', timeout=900)
    strays = [path.name for path in elsewhere.rglob('*') if path.is_file()]
    report.add('7 outputs', 'optimise with DIR/params and DIR/evaluations as links',
               code in (0, 1) and not strays, f'{seconds:.1f} s: outside --out: {strays}')


def attack_checks(report, folder):
    """Class 8: every window and bound within the run; check time linear in the file."""
    from test_hostile_scenarios import BASE, REFUSED

    for changes, events, expectation, key in REFUSED:
        path = folder / f'check_{len(os.listdir(folder))}.yaml'
        path.write_text(BASE % (changes, events, expectation))
        refusal(report, '8 checks', f'scenario check: {expectation or changes or events}'[:44],
                'scenario', 'check', path, also=key.split('.')[-1])
    seconds = {}
    for changes in (2_500, 25_000):
        path = folder / f'changes_{changes}.yaml'
        duration = 3600 * changes // 25_000
        path.write_text(
            f'duration: {duration}\ninputs:\n  inlet_flow:\n    initial: 5 L/min\n    changes:\n'
            + ''.join(f'      - {{at: {(k + 0.5) * duration / changes:.6f}, step: '
                      f'{5 + k % 10} L/min}}\n' for k in range(changes))
            + 'expect: [{no_alarm: {}}]\n')
        code, line, seconds[changes] = valve_sim('scenario', 'check', path, timeout=600)
    ratio = seconds[25_000] / seconds[2_500]
    report.add('8 checks', 'scenario check: 25,000 changes over 3,600 s', ratio < 30,
               f'{seconds[25_000]:.1f} s, {ratio:.1f}x the time of a tenth the file')


def attack_budgets(report, context, folder):
    """Class 9: a 50 MB line, NaN, ±-1%, bad wait topics, a missing extra, a flapping tank."""
    import resource

    from sensor_msgs.msg import FluidPressure
    from valve_harness import running_valve

    evaluations = folder / 'opt' / 'evaluations'
    evaluations.mkdir(parents=True)
    (evaluations / 'generation_001.jsonl').write_text('{"x": "' + 'x' * 50_000_000 + '"}\n')

    def limited():
        resource.setrlimit(resource.RLIMIT_AS, (6_000_000 * 1024,) * 2)
    started = time.monotonic()
    result = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'optimise', '--design', 'd_c=±5%',
         '--minimise', 'P_1_percent', '--tolerance', 'd_c=±5um', '--out', str(folder / 'opt'),
         '--resume', '--population', '4', '--generations', '1', '--samples', '2',
         '--workers', '1'], capture_output=True, text=True, timeout=900, cwd=REPO,
        preexec_fn=limited)
    line = (result.stderr.strip().splitlines() or [''])[-1]
    report.add('9 budgets', 'optimise --resume: a 50 MB line, ulimit -v 6 GB',
               result.returncode in (0, 1) and 'Traceback' not in result.stderr
               and 'MemoryError' not in result.stderr,
               f'{time.monotonic() - started:.1f} s: {line[-60:]}')
    refusal(report, '9 budgets', 'simulate --set k_p=nan', 'simulate', '--set', 'k_p=nan',
            also='got nan')
    refusal(report, '9 budgets', "optimise --tolerance 'd_c=±-1%'", 'optimise', '--design',
            'd_c=±5%', '--minimise', 'P_1_percent', '--tolerance', 'd_c=±-1%', '--out',
            folder / 'neg', also='>= 0')
    for topic in ('bad topic!!', ''):
        refusal(report, '9 budgets', f'scenario run --wait-topic {topic!r}', 'scenario', 'run',
                REPO / 'scenarios/paper_step.yaml', '--wait-topic', topic, '--out',
                folder / 'wait', also='not a ROS topic name', within=15)
    blocked = ('import sys; sys.modules["pythonfmu"] = None; '
               'from valve_sim.commands.cli import main; sys.exit(main(sys.argv[1:]))')
    result = subprocess.run([sys.executable, '-c', blocked, 'fmu', '--out', str(folder / 'v.fmu')],
                            capture_output=True, text=True, timeout=120, cwd=REPO)
    report.add('9 budgets', 'valve-sim fmu without the fmu extra',
               result.returncode == 1 and "'fmu' extra" in result.stderr
               and 'Traceback' not in result.stderr, result.stderr.strip()[-70:])
    log = folder / 'valve_node_tank.log'
    with running_valve(context, log, namespace='/attack_tank') as (process, probe):
        node = rclpy_node(context, 'attack_tank_publisher', '/attack_tank')
        publisher = node.create_publisher(FluidPressure, 'tank_pressure', 100)
        ambient, flips, deadline = 101_325.0, 0, time.monotonic() + 5.0
        while time.monotonic() < deadline:
            publisher.publish(FluidPressure(fluid_pressure=ambient + 30e6 * (flips % 2)))
            flips += 1
            time.sleep(0.002)
        node.destroy_node()
        alive = process.poll() is None
    errors = [text for text in log.read_text(errors='replace').splitlines() if 'ERROR' in text]
    report.add('9 budgets', 'tank pressure flipping 0 / 30 MPa for 5 s',
               alive and len(errors) <= 20,
               f'{flips} flips: {len(errors)} ERROR lines, {log.stat().st_size} bytes of log')


def rclpy_node(context, name, namespace):
    import rclpy

    return rclpy.create_node(name, namespace=namespace, context=context)


def check_imports():
    """Import every suite module each class uses; return the failures [(step, module, error)]."""
    import importlib

    failures = []
    for step, modules in CLASS_MODULES.items():
        for module in modules:
            try:
                importlib.import_module(module)
            except Exception as error:  # noqa: B902  (any failure to import is the finding)
                failures.append((step, module, f'{type(error).__name__}: {error}'))
    return failures


def measure(args):
    import rclpy

    report, started = Report(), time.monotonic()
    context = rclpy.Context()
    rclpy.init(context=context)
    with tempfile.TemporaryDirectory(prefix='valve_sim_attack_') as folder:
        folder = Path(folder)
        steps = {
            'live': lambda path: attack_live_schedules(report, context, path, args.schedule),
            'readers': lambda path: attack_readers(report, path),
            'sim': lambda path: attack_clock_and_roll_backs(report, context, path),
            'wire': lambda path: attack_wire(report, path),
            'recordings': lambda path: attack_recordings(report, path),
            'rogue_type': lambda path: attack_rogue_type(report, context, path),
            'options': lambda path: attack_options(report, path),
            'outputs': lambda path: attack_outputs(report, path),
            'checks': lambda path: attack_checks(report, path),
            'budgets': lambda path: attack_budgets(report, context, path),
        }
        for step, module, error in check_imports():
            report.add('imports', f'{step}: {module}', False, error[:200])
        for name, step in steps.items():
            if args.only and name not in args.only:
                continue
            (folder / name).mkdir()
            try:
                step(folder / name)
            except Exception as error:  # noqa: B902  (an attack that broke the bench failed)
                report.add('error', name, False, f'{type(error).__name__}: {error}'[:200])
    context.try_shutdown()
    return {'seconds': time.monotonic() - started, 'attacks': report.rows}, report


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--json', type=Path, default=REPO / 'out' / 'attack.json')
    parser.add_argument('--only', action='append', choices=tuple(CLASS_MODULES),
                        help='run only this attack step (repeatable; default: all)')
    parser.add_argument('--schedule', metavar='TEXT',
                        help='live: only the hostile schedules whose name holds TEXT')
    parser.add_argument('--check-imports', action='store_true',
                        help="only import each class's suite modules; exit 1 naming any that fail")
    args = parser.parse_args()
    if args.check_imports:
        failures = check_imports()
        for step, module, error in failures:
            print(f'{step}: {module}: {error}', file=sys.stderr)
        return 1 if failures else 0
    isolated_environment()
    figures, report = measure(args)
    write_figures(figures, report.table(figures), args.json)
    return 0 if all(row['survived'] for row in report.rows) else 1


if __name__ == '__main__':
    sys.exit(main())
