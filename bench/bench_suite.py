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

"""Benchmark suites on one valve_node against a process per scenario or test (issue 46)."""

# The summary above is also this script's --help description.
#
#     nice python bench/bench_suite.py [--scenarios 20] [--alone 3] [--tests 10]
#                                      [--parts scenarios,kit] [--json F]
#
# In one run, on a ROS domain of its own (localhost only), side by side:
#
# - alone: `valve-sim scenario run FILE` of --alone of the short scenarios, a command
#   each (today's way); its overhead per scenario is the command's wall time less its
#   lockstep stepping (report.json run.wall_s): the nodes' start, discovery, stop;
# - suite: `valve-sim scenario run DIR` of the first scenario alone as a folder, then of
#   all --scenarios: the overhead per scenario after the first is (wall of the suite
#   - wall of the one-scenario suite - the stepping of scenarios 2..N) / (N - 1):
#   its restart of valve_node, its own analyser_node, discovery, the bag and reports;
# - kit: --tests tests of 10 ms of model time each, a LockstepValve per test (start,
#   close) against one LockstepValve restarted before each (the session fixture's
#   way: apart, the same driver); the per-test overhead is the time per test less the
#   advance's own; the process's start and close and the restart's ~/restart round
#   trip are reported apart.
#
# Targets (issue 46): suite overhead per scenario <= 0.1 x alone's; kit overhead per
# test <= 0.1 x a process per test's. The load average at start and end is printed.

import argparse
import json
import os
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time

from common import isolated_environment, REPO


SCENARIO = """scenario: short_{index:02d}
duration: 0.1
valve: {{parameters: {{preset_pressure: {preset} MPa}}}}
inputs: {{inlet_flow: {{initial: {flow} L/min, changes: [{{at: 0.03, step: 20 L/min}}]}}}}
expect:
  - no_alarm: {{}}
"""


def write_scenarios(folder, count):
    """Write count short scenarios (0.1 s, a step, presets and flows varied) into folder."""
    folder.mkdir(parents=True)
    for index in range(count):
        (folder / f'short_{index:02d}.yaml').write_text(SCENARIO.format(
            index=index, preset=6 + index % 3 * 0.5, flow=4 + index % 5))
    return sorted(folder.glob('*.yaml'))


def command(paths, out, env):
    """Run `valve-sim scenario run PATHS --out OUT`; return its wall time [s]."""
    started = time.monotonic()
    completed = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'scenario', 'run', *map(str, paths),
         '--out', str(out)], env=env, capture_output=True, text=True)
    wall = time.monotonic() - started
    if completed.returncode != 0:
        raise SystemExit(f'scenario run failed:\n{completed.stdout}\n{completed.stderr}')
    return wall


def stepping(folder):
    """Return the lockstep stepping [s] of each report.json under folder, in name order."""
    return [json.loads(path.read_text())['run']['wall_s']
            for path in sorted(folder.rglob('report.json'))]


def measure_scenarios(work, count, alone, env):
    files = write_scenarios(work / 'scenarios', count)
    overheads = []
    for index, path in enumerate(files[:alone]):
        wall = command([path], work / f'alone_{index}', env)
        overheads.append(wall - stepping(work / f'alone_{index}')[0])
    single = work / 'single'
    single.mkdir()
    (single / files[0].name).write_text(files[0].read_text())
    one = command([single], work / 'suite_1', env)
    whole = command([work / 'scenarios'], work / 'suite_all', env)
    rest = sum(stepping(work / 'suite_all')[1:])
    return {'alone_overhead_s': overheads, 'alone_overhead_median_s': statistics.median(overheads),
            'suite_1_wall_s': one, 'suite_all_wall_s': whole, 'suite_steps_after_first_s': rest,
            'suite_overhead_per_scenario_s': (whole - one - rest) / (count - 1)}


def measure_kit(work, tests):
    from valve_sim.testing import LockstepValve

    def one_test(valve):
        started = time.monotonic()
        valve.advance(0.01)
        return time.monotonic() - started

    per_process, advances, starts, closes = [], [], [], []
    for index in range(tests):
        started = time.monotonic()
        valve = LockstepValve(folder=work / f'kit_{index}')
        starts.append(time.monotonic() - started)
        advances.append(one_test(valve))
        closing = time.monotonic()
        valve.close()
        closes.append(time.monotonic() - closing)
        per_process.append(time.monotonic() - started)
    shared, shared_advances, restarts, requests = [], [], [], []
    valve = LockstepValve(folder=work / 'kit_session', apart=True)  # the session fixture's
    driver, request = valve._driver, valve._driver.request_restart
    driver.request_restart = lambda *a: requests.append(timed(request, *a))  # the round trip
    try:
        for _ in range(tests):
            started = time.monotonic()
            valve.restart()
            restarts.append(time.monotonic() - started)
            shared_advances.append(one_test(valve))
            shared.append(time.monotonic() - started)
    finally:
        valve.close()
    return {'process_per_test_s': statistics.median(per_process),
            'process_overhead_s': statistics.median(per_process) - statistics.median(advances),
            'process_start_s': statistics.median(starts),
            'process_close_s': statistics.median(closes),
            'session_per_test_s': statistics.median(shared),
            'session_overhead_s': statistics.median(shared) - statistics.median(shared_advances),
            'session_restart_s': statistics.median(restarts),
            'session_restart_round_trip_s': statistics.median(requests),
            'advance_10ms_s': statistics.median(advances + shared_advances)}


def timed(call, *args):
    """Return the wall time [s] of call(*args)."""
    started = time.monotonic()
    call(*args)
    return time.monotonic() - started


def table(figures):
    lines = [f"load average {figures['load_start']:.1f} -> {figures['load_end']:.1f}"]
    if 'scenarios' in figures:
        s = figures['scenarios']
        suite_ratio = s['suite_overhead_per_scenario_s'] / s['alone_overhead_median_s']
        lines += [
            f"scenario overhead alone (a command each): {s['alone_overhead_median_s']:.2f} s "
            f"(median of {len(s['alone_overhead_s'])})",
            f"suite of {figures['count']}: {s['suite_all_wall_s']:.2f} s; one-scenario suite "
            f"{s['suite_1_wall_s']:.2f} s; overhead per scenario after the first "
            f"{s['suite_overhead_per_scenario_s']:.3f} s = {suite_ratio:.3f} x alone "
            '(target <= 0.1)']
    if 'kit' in figures:
        k = figures['kit']
        kit_ratio = k['session_overhead_s'] / k['process_overhead_s']
        lines += [
            f"kit per test: a process {k['process_per_test_s']:.2f} s (overhead "
            f"{k['process_overhead_s']:.2f} s: start {k['process_start_s']:.2f} s, close "
            f"{k['process_close_s']:.2f} s); session fixture {k['session_per_test_s']:.4f} s "
            f"(overhead {k['session_overhead_s']:.4f} s = {kit_ratio:.4f} x, target <= 0.1; "
            f"restart {k['session_restart_s'] * 1e3:.2f} ms, of it the ~/restart round trip "
            f"{k['session_restart_round_trip_s'] * 1e3:.2f} ms); advance(0.01) "
            f"{k['advance_10ms_s'] * 1e3:.2f} ms"]
    return '\n'.join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--scenarios', type=int, default=20, help='short scenarios in the suite')
    parser.add_argument('--alone', type=int, default=3, help='of them run a command each')
    parser.add_argument('--tests', type=int, default=10, help='kit tests each way')
    parser.add_argument('--parts', default='scenarios,kit',
                        help='what to measure, comma-separated: scenarios, kit')
    parser.add_argument('--json', type=Path, default=REPO / 'out' / 'bench_suite.json')
    args = parser.parse_args()
    parts = set(args.parts.split(','))
    env = isolated_environment()
    figures = {'count': args.scenarios, 'load_start': os.getloadavg()[0]}
    with tempfile.TemporaryDirectory(prefix='bench_suite_') as work:
        if 'scenarios' in parts:
            figures['scenarios'] = measure_scenarios(Path(work), args.scenarios, args.alone,
                                                     env)
        if 'kit' in parts:
            figures['kit'] = measure_kit(Path(work), args.tests)
    figures['load_end'] = os.getloadavg()[0]
    print(table(figures))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(figures, indent=2) + '\n')
    print(f'figures written to {args.json}')


if __name__ == '__main__':
    main()
