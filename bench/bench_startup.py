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

"""Benchmark valve_node's start-up, warm and cold, beside a bare rclpy node's (issue 8)."""

# The summary above is also this script's --help description.
#
#     python bench/bench_startup.py [--warm 5] [--cold 2] [--json out/bench_startup.json]
#
# Measures, in one run on a ROS domain of its own (localhost only), the time from
# starting a node process to receiving its first supply_pressure message here:
#
# - bare: a minimal rclpy node (python -c ...) that publishes FluidPressure at 1 kHz,
#   the floor that Python, rclpy and DDS discovery alone set on this machine;
# - warm: valve_node with its kernels in numba's cache;
# - cold: valve_node with an empty kernel cache (NUMBA_CACHE_DIR set to a new empty
#   folder: the cache beside the sources is not touched), as on a fresh clone or a
#   fresh colcon install.
#
# The warm runs use the cache the first cold run filled. Runs alternate between
# the kinds, so load from other work on the machine spreads over all of them; the
# load average at start and end is printed. valve_node's own "ready" log line gives
# the part spent computing the steady state and compiling or loading the kernels.
# Target (issue 8): warm start-up <= 2 s on the development machine (2 cores).

import argparse
import json
import os
from pathlib import Path
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time

from valve_sim.ros.isolation import claim_domain


REPO = Path(__file__).resolve().parent.parent
TIMEOUT = 300.0  # [s] for one start-up (a cold compile on a loaded machine)
BARE_NODE = (
    'import rclpy\n'
    'from sensor_msgs.msg import FluidPressure\n'
    'rclpy.init()\n'
    "node = rclpy.create_node('bare')\n"
    "publisher = node.create_publisher(FluidPressure, 'supply_pressure', 1000)\n"
    'node.create_timer(0.001, lambda: publisher.publish(FluidPressure(fluid_pressure=1.0)))\n'
    'try:\n'
    '    rclpy.spin(node)\n'
    'except KeyboardInterrupt:\n'
    '    pass\n'
)
READY = re.compile(r'compiled or loaded in ([0-9.]+) s')


class FirstMessage:
    """A subscriber here, per namespace: when did the first supply_pressure arrive."""

    def __init__(self):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor

        rclpy.init()
        self.node = rclpy.create_node('startup_probe')
        self.arrived = {}  # namespace: time.monotonic() of its first message
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        threading.Thread(target=self.executor.spin, daemon=True).start()

    def watch(self, namespace):
        from sensor_msgs.msg import FluidPressure

        def first(_):
            self.arrived.setdefault(namespace, time.monotonic())

        return self.node.create_subscription(
            FluidPressure, f'{namespace}/supply_pressure', first, 10
        )


def start_up(probe, kind, index, cache):
    """Start one node of kind, return (seconds to its first message, its ready seconds)."""
    namespace = f'/{kind}{index}'
    subscription = probe.watch(namespace)
    env = dict(os.environ, PYTHONUNBUFFERED='1', NUMBA_CACHE_DIR=str(cache))
    if kind == 'bare':
        command = [sys.executable, '-c', BARE_NODE]
    else:
        command = [sys.executable, '-m', 'valve_sim.ros.valve_node']
    command += ['--ros-args', '-r', f'__ns:={namespace}']
    with tempfile.TemporaryFile('w+') as log:
        started = time.monotonic()
        process = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, env=env)
        try:
            while namespace not in probe.arrived:
                if process.poll() is not None or time.monotonic() - started > TIMEOUT:
                    log.seek(0)
                    raise RuntimeError(f'{kind} node gave no state: {log.read()[-2000:]}')
                time.sleep(0.005)
        finally:
            process.terminate()
            process.wait(timeout=60)
        log.seek(0)
        ready = READY.search(log.read())
    probe.node.destroy_subscription(subscription)
    return probe.arrived[namespace] - started, float(ready[1]) if ready else None


def summary(values):
    return {
        'runs': len(values),
        'median_s': statistics.median(values),
        'min_s': min(values),
        'max_s': max(values),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--warm', type=int, default=5, help='warm runs (and bare runs)')
    parser.add_argument('--cold', type=int, default=2, help='cold runs (empty kernel cache)')
    parser.add_argument('--json', type=Path, help='also write the figures as JSON')
    args = parser.parse_args()
    claim_domain(keep_existing=False)
    os.environ['PYTHONPATH'] = os.pathsep.join(
        filter(None, [str(REPO), os.environ.get('PYTHONPATH')])
    )
    load_start = os.getloadavg()
    probe = FirstMessage()
    times = {'bare': [], 'warm': [], 'cold': []}
    ready = {'warm': [], 'cold': []}
    with tempfile.TemporaryDirectory(prefix='bench_startup_') as folder:
        shared = Path(folder) / 'cache'  # filled by the first cold run, used by the warm ones
        plan = (
            [('cold', 0)]
            + [(kind, i) for i in range(args.warm) for kind in ('bare', 'warm')]
            + [('cold', i) for i in range(1, args.cold)]
        )
        for kind, i in plan:
            cache = shared if kind != 'cold' or i == 0 else Path(folder) / f'cold{i}'
            seconds, ready_seconds = start_up(probe, kind, i, cache)
            times[kind].append(seconds)
            if kind != 'bare':
                ready[kind].append(ready_seconds)
            print(
                f'{kind:<5} run {i + 1}: first state after {seconds:6.2f} s'
                + (f' (steady state + kernels {ready_seconds:.2f} s)' if ready_seconds else ''),
                flush=True,
            )
    figures = {
        'load_average_start': load_start,
        'load_average_end': os.getloadavg(),
        **{kind: summary(values) for kind, values in times.items() if values},
        **{
            f'{kind}_kernels': summary([v for v in values if v is not None])
            for kind, values in ready.items()
            if any(v is not None for v in values)
        },
    }
    print()
    print(f'{"start-up to first state":<34}{"median":>9}{"min":>9}{"max":>9}')
    for kind, label in (
        ('bare', 'bare rclpy node'),
        ('warm', 'valve_node, kernels cached'),
        ('cold', 'valve_node, empty kernel cache'),
        ('warm_kernels', '  of which steady state + kernels'),
        ('cold_kernels', '  of which steady state + kernels'),
    ):
        if kind in figures:
            f = figures[kind]
            print(f'{label:<34}{f["median_s"]:8.2f}s{f["min_s"]:8.2f}s{f["max_s"]:8.2f}s')
    print(
        f'load average {load_start[0]:.2f} at start, {figures["load_average_end"][0]:.2f} at end'
    )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(figures, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
