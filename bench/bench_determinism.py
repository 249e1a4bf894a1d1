#!/usr/bin/env python3
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
Lockstep determinism under load: every run of a scenario completes and records the same bag.

Runs the shipped example scenarios and three whose inputs change every tick (a flow
ramp, a flow sine, a tank-pressure profile under a ramped flow), each --runs times
with `valve-sim scenario run` as a user types it, while a busy loop spins on every
core (--no-load: without). A run passes when it exits as its verdict says (0, or 1
for stuck_main_valve's failing check: never an error) and its bag's valve topics and
inputs, messages, log and publish times (model time), are the same bytes as the first
run's (scenario_runner.lockstep_messages). Prints a line per run and a summary (with a
digest of each scenario's messages, to compare benches); writes the results as JSON,
and the logs and reports of a run that fails beside it (bench_determinism_failures/).

    nice -n 10 .venv/bin/python bench/bench_determinism.py --runs 20
"""

import argparse
import hashlib
import json
import multiprocessing
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
import time


REPO = Path(__file__).resolve().parent.parent
PROFILES = {
    'flow_ramp': 'duration: 1.0\ninputs:\n  inlet_flow:\n    initial: 5 L/min\n'
                 '    changes:\n      - {at: 0.1, ramp: 25 L/min, over: 0.6}\n'
                 'expect:\n  - no_alarm: {}\n',
    'flow_sine': 'duration: 1.0\ninputs:\n  inlet_flow:\n    initial: 12 L/min\n'
                 '    changes:\n      - {at: 0.1, sine: {amplitude: 6 L/min, frequency: 7}}\n'
                 'expect:\n  - no_alarm: {}\n',
    'tank_profile': 'duration: 1.0\ninputs:\n  inlet_flow:\n    initial: 5 L/min\n'
                    '    changes:\n      - {at: 0.2, ramp: 15 L/min, over: 0.5}\n'
                    '  tank_pressure:\n    initial: 0 bar\n    changes:\n'
                    '      - {at: 0.1, ramp: 4 bar, over: 0.4}\n'
                    '      - {at: 0.6, sine: {amplitude: 1 bar, frequency: 5}}\n'
                    'expect:\n  - no_alarm: {}\n',
}
EXAMPLES = {'paper_step': 0, 'stuck_main_valve': 0}  # name: the exit code as shipped


def busy_loop():
    while True:
        pass


def scenario_files(folder):
    """Return {name: (path, expected exit code)}: the examples and the profiles."""
    files = {name: (REPO / 'scenarios' / f'{name}.yaml', code) for name, code in EXAMPLES.items()}
    for name, text in PROFILES.items():
        path = folder / f'{name}.yaml'
        path.write_text(text)
        files[name] = (path, 0)
    return files


def digest(messages):
    """Return a SHA-256 of a run's recorded messages: to compare runs of separate benches."""
    hashed = hashlib.sha256()
    for topic in sorted(messages):
        for log_time, publish_time, data in messages[topic]:
            hashed.update(f'{topic} {log_time} {publish_time} {len(data)}'.encode() + data)
    return hashed.hexdigest()


def run_once(path, out):
    """
    Run a scenario; returns (exit code, wall [s], real-time factor or None, stderr tail).

    The command's output (progress lines: how far the run got) goes to out/command.txt.
    """
    started = time.monotonic()
    completed = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'scenario', 'run', str(path),
         '--out', str(out)], capture_output=True, text=True, timeout=900)
    wall = time.monotonic() - started
    out.mkdir(parents=True, exist_ok=True)
    (out / 'command.txt').write_text(completed.stdout + completed.stderr)
    factor = None
    report = out / 'report.json'
    if report.exists():
        factor = json.loads(report.read_text())['run']['real_time_factor']
    return completed.returncode, wall, factor, completed.stderr.strip().splitlines()[-1:]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--runs', type=int, default=20, help='runs of each scenario')
    parser.add_argument('--only', nargs='*', help='scenario names (default: all)')
    parser.add_argument('--no-load', action='store_true', help='no busy loops')
    parser.add_argument('--json', type=Path, default=REPO / 'out' / 'bench_determinism.json')
    args = parser.parse_args()
    from valve_sim.ros.scenario_runner import lockstep_messages

    loops = [] if args.no_load else [multiprocessing.Process(target=busy_loop, daemon=True)
                                     for _ in range(os.cpu_count())]
    for loop in loops:
        loop.start()
    results = {}
    try:
        with tempfile.TemporaryDirectory(prefix='bench_determinism_') as temporary:
            folder = Path(temporary)
            for name, (path, expected_code) in scenario_files(folder).items():
                if args.only and name not in args.only:
                    continue
                first, runs = None, []
                for run in range(args.runs):
                    out = folder / f'{name}_{run}'
                    code, wall, factor, tail = run_once(path, out)
                    bags = sorted(out.glob('*.mcap'))
                    complete = bags and code == expected_code
                    messages = lockstep_messages(bags[0]) if complete else None
                    first = first if first is not None else messages
                    same = messages is not None and messages == first
                    count = sum(map(len, messages.values())) if messages else 0
                    runs.append({'exit': code, 'wall_s': wall, 'real_time_factor': factor,
                                 'messages': count, 'identical': same, 'error': tail})
                    print(f'{name} run {run + 1}: exit {code}, {count} messages, '
                          f'{"identical" if same else "DIFFERENT"}, {wall:.1f} s'
                          + (f', {factor:.2f}x real time' if factor else '')
                          + ('' if code == expected_code else f': {tail}'), flush=True)
                    if not same:  # keep what says why, past the temporary folder
                        kept = args.json.parent / 'bench_determinism_failures' / out.name
                        kept.mkdir(parents=True, exist_ok=True)
                        for log in (*out.glob('*.log'), *out.glob('report.*'),
                                    out / 'command.txt'):
                            shutil.copy(log, kept)
                    for bag in bags:
                        bag.unlink()
                ok = sum(r['exit'] == expected_code and r['identical'] for r in runs)
                factors = sorted(r['real_time_factor'] for r in runs if r['real_time_factor'])
                results[name] = {'runs': runs, 'complete_and_identical': ok,
                                 'digest': digest(first) if first else None,
                                 'median_real_time_factor':
                                     factors[len(factors) // 2] if factors else None}
                print(f'{name}: {ok} of {args.runs} runs complete and identical', flush=True)
    finally:
        for loop in loops:
            loop.terminate()
    load = os.getloadavg()[0]
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({'load_at_end': load, 'busy_loops': len(loops),
                                     'scenarios': results}, indent=1) + '\n')
    print('summary: ' + '; '.join(
        f'{name} {r["complete_and_identical"]}/{args.runs}'
        + (f' ({r["median_real_time_factor"]:.2f}x, {(r["digest"] or "-")[:12]})'
           if r['median_real_time_factor'] else '')
        for name, r in results.items()) + f'; load {load:.1f} at the end')
    return 0 if all(r['complete_and_identical'] == args.runs for r in results.values()) else 1


if __name__ == '__main__':
    sys.exit(main())
