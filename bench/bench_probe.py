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

"""Benchmark the node tests' probe (test/valve_harness.py) per executor, cores busy (issue 8)."""

# The summary above is also this script's --help description.
#
#     python bench/bench_probe.py [--duration 60] [--busy N] [--json out/bench_probe.json]
#                                 [--executor {events,single-threaded}]
#
# The node tests read valve_node through a Probe: one node in the test process
# that subscribes to the valve's six tick topics (6,000 messages/s at 1 kHz) and
# calls its parameter services. One run, on a ROS domain of its own (localhost
# only), with --busy busy loops (default: one per core, as bench/stress_suite.sh
# loads the machine) running throughout: for each probe executor in turn, a fresh
# valve_node (on --executor) and a probe, for --duration seconds. Every
# CHECK_PERIOD the probe's newest supply_pressure sample is aged (wall clock now
# minus its stamp) and one get_parameters call is timed. Reported per executor:
# the supply_pressure samples the probe received per second (valve_node publishes
# one a tick: at most 1000), the median and maximum age of the newest sample, and
# the median and maximum service answer. A probe that keeps up has an age near 0
# and answers in milliseconds; the suite's waits time out at 60 s. The load
# average at start and end is reported.

import os
from pathlib import Path
import statistics
import subprocess
import sys
import tempfile
import time

from common import arguments, REPO, run_benchmark


CHECK_PERIOD = 5.0  # [s] between two checks of the probe
BUSY_LOOP = ('bash', '-c', 'while :; do :; done')


def measure_probe(executor_name, duration, log_path, valve_executor):
    """Run a valve and a probe on executor_name for duration [s]; return its figures."""
    import rclpy
    from valve_harness import running_valve
    from valve_sim.ros.spinning import EXECUTORS

    context = rclpy.Context()
    rclpy.init(context=context)
    ages, answers = [], []
    try:
        valve = running_valve(
            context,
            log_path,
            options=('--executor', valve_executor),
            probe_executor=EXECUTORS[executor_name],
        )
        with valve as (_, probe):
            first_count = probe.count()
            started = time.monotonic()
            while time.monotonic() - started < duration:
                time.sleep(CHECK_PERIOD)
                asked = time.monotonic()
                probe.get_parameters('preset_pressure')
                answers.append(time.monotonic() - asked)
                ages.append(time.time() - probe.latest()[0] / 1e9)
            elapsed = time.monotonic() - started
            received = probe.count() - first_count
    finally:
        context.try_shutdown()
    return {
        'received_per_s': received / elapsed,
        'newest_age_median_s': statistics.median(ages),
        'newest_age_max_s': max(ages),
        'service_answer_median_s': statistics.median(answers),
        'service_answer_max_s': max(answers),
    }


def measure(args, env):
    from valve_sim.ros.spinning import EXECUTORS

    sys.path.insert(0, str(REPO / 'test'))  # the probe is the suite's
    busy = [subprocess.Popen(BUSY_LOOP) for _ in range(args.busy)]
    figures = {
        'busy_loops': args.busy,
        'duration_s': args.duration,
        'valve_executor': args.executor,
        'load_start': os.getloadavg()[0],
    }
    try:
        with tempfile.TemporaryDirectory() as folder:
            for name in EXECUTORS:
                figures[name] = measure_probe(
                    name, args.duration, Path(folder) / f'{name}.log', args.executor
                )
    finally:
        for process in busy:
            process.kill()
            process.wait()
    figures['load_end'] = os.getloadavg()[0]
    return figures


def table(figures):
    from valve_sim.ros.spinning import EXECUTORS

    lines = [
        f"probe for {figures['duration_s']:.0f} s per executor, {figures['busy_loops']} busy"
        f" loops, valve_node on {figures['valve_executor']},"
        f" load {figures['load_start']:.1f} -> {figures['load_end']:.1f}",
        '| probe executor | supply samples received /s | newest sample age (median, max)'
        ' | service answer (median, max) |',
        '|---|---|---|---|',
    ]
    for name in EXECUTORS:
        f = figures[name]
        lines.append(
            f"| {name} | {f['received_per_s']:.0f}"
            f" | {f['newest_age_median_s']:.2f} s, {f['newest_age_max_s']:.2f} s"
            f" | {f['service_answer_median_s'] * 1e3:.1f} ms,"
            f" {f['service_answer_max_s'] * 1e3:.1f} ms |"
        )
    return '\n'.join(lines)


def main():
    parser = arguments(__doc__, 'bench_probe.json', 'measurement per executor')
    parser.add_argument(
        '--busy',
        type=int,
        default=os.cpu_count(),
        help=f'busy loops running throughout (default {os.cpu_count()}: one per core)',
    )
    return run_benchmark(parser.parse_args(), {}, measure, table)


if __name__ == '__main__':
    sys.exit(main())
