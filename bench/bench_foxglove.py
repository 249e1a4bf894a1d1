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

"""Benchmark valve_node's tick with the Foxglove live view: no viewer, a viewer, no --foxglove."""

# The summary above is also this script's --help description.
#
#     python bench/bench_foxglove.py [--phase 15] [--cycles 2] [--json out/bench_foxglove.json]
#
# Three valve_nodes run side by side in one run, each in its own process and
# namespace, on a domain of this run's own (localhost only): "plain" and "control"
# without --foxglove, "served" with --foxglove on a free port. Phases of --phase seconds
# alternate, --cycles times: nobody connected to served, then a viewer connected
# (a WebSocket client in this process that subscribes to every channel, as the
# Foxglove app does for a layout, and receives every message). Per phase and node:
# the tick compute time (the node's own p50 and p99 of each 1-s /diagnostics
# window, their median over the phase), the ticks and the late ticks.
#
# Reported: served / plain ratios of the tick compute p50 and p99, per phase kind,
# all nodes measured over the same seconds, so the machine's load falls on all;
# and control / plain, the same ratio between two identical nodes: the noise floor
# of these figures on this machine. Without a viewer, served / plain within the
# control's spread means the live view costs the tick nothing; with one, the ratio
# is what serving a viewer costs. Also the messages the viewer received per second.
# Other work on the machine shows in every figure.

import argparse
import asyncio
import json
import os
from pathlib import Path
import re
import statistics
import subprocess
import sys
import threading
import time


REPO = Path(__file__).resolve().parent.parent
NODES = {'plain': [], 'control': [], 'served': ['--foxglove', '0']}
WARM_UP = 5.0  # [s] after both nodes publish: discovery, first ticks, the JIT
SETTLE = 2.0  # [s] at the start of each phase, not measured (a report window spans it)


def start_node(name, options, folder):
    log = open(folder / f'{name}.log', 'w')
    return subprocess.Popen(
        [sys.executable, '-m', 'valve_sim.ros.valve_node_main', *options, '--ros-args', '-r',
         f'__ns:=/{name}'],
        stdout=log,
        stderr=subprocess.STDOUT,
        env=dict(os.environ, PYTHONUNBUFFERED='1'),
        cwd=REPO,
    )


class Viewer:
    """A Foxglove WebSocket client in a thread: subscribes to every channel while connected."""

    def __init__(self, port):
        self.port, self.received, self._stop = port, 0, None
        self._ready = threading.Event()
        self._thread = None

    def connect(self):
        self.received, self._ready = 0, threading.Event()
        self._thread = threading.Thread(target=lambda: asyncio.run(self._run()), daemon=True)
        self._thread.start()
        if not self._ready.wait(60.0):
            raise TimeoutError('the viewer did not connect and subscribe within 60 s')

    def disconnect(self):
        self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(30.0)

    async def _run(self):
        import websockets

        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        async with websockets.connect(
            f'ws://127.0.0.1:{self.port}', subprotocols=['foxglove.sdk.v1'], max_queue=None
        ) as socket:
            channels = []
            while not channels:
                frame = await socket.recv()
                if isinstance(frame, str) and json.loads(frame)['op'] == 'advertise':
                    channels = json.loads(frame)['channels']
            subscriptions = [{'id': k, 'channelId': c['id']} for k, c in enumerate(channels)]
            await socket.send(json.dumps({'op': 'subscribe', 'subscriptions': subscriptions}))
            self._ready.set()
            receiving = asyncio.ensure_future(self._receive(socket))
            await self._stop.wait()
            receiving.cancel()

    async def _receive(self, socket):
        async for frame in socket:
            self.received += isinstance(frame, bytes)


def collect_diagnostics(node, windows):
    """Append (receive time [s], node name, {key: value}) of both valves' statuses."""
    from diagnostic_msgs.msg import DiagnosticArray

    def on_diagnostics(message):
        for status in message.status:
            found = re.fullmatch(r'/(\w+)/relief_valve', status.hardware_id)
            if found and found[1] in NODES:
                values = {kv.key: kv.value for kv in status.values}
                windows.append((time.monotonic(), found[1], values))

    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)


def phase_figures(windows, start, end):
    """{node: {p50_ms, p99_ms, ticks, late_ticks}} of the reports received in [start, end]."""
    figures = {}
    for name in NODES:
        inside = [v for t, n, v in windows if n == name and start <= t <= end]
        if len(inside) < 2:
            raise RuntimeError(f'{name}: fewer than 2 diagnostics reports in a phase')
        p50 = [float(v['tick_compute_p50_ms']) for v in inside if v['tick_compute_p50_ms']]
        p99 = [float(v['tick_compute_p99_ms']) for v in inside if v['tick_compute_p99_ms']]
        figures[name] = {
            'p50_ms': statistics.median(p50),
            'p99_ms': statistics.median(p99),
            'ticks': int(inside[-1]['ticks']) - int(inside[0]['ticks']),
            'late_ticks': int(inside[-1]['late_ticks']) - int(inside[0]['late_ticks']),
        }
    return figures


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--phase', type=float, default=15.0, help='seconds per phase')
    parser.add_argument('--cycles', type=int, default=2, help='(no viewer, viewer) pairs')
    parser.add_argument('--json', metavar='FILE', help='write the figures as JSON')
    args = parser.parse_args(argv)

    from valve_sim.ros.isolation import claim_domain

    claim_domain(keep_existing=False)
    import tempfile

    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    folder = Path(tempfile.mkdtemp(prefix='bench_foxglove_'))
    processes = {name: start_node(name, options, folder) for name, options in NODES.items()}
    rclpy.init()
    node = rclpy.create_node('bench_foxglove')
    windows = []
    collect_diagnostics(node, windows)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    load_start = os.getloadavg()
    phases = []
    try:
        deadline = time.monotonic() + 120.0
        while {n for _, n, _ in windows} != set(NODES):
            ended = any(process.poll() is not None for process in processes.values())
            if ended or time.monotonic() > deadline:
                raise RuntimeError(f'the nodes did not report (logs in {folder})')
            time.sleep(0.1)
        port = int(re.search(r'live view on ws://127\.0\.0\.1:(\d+)',
                             (folder / 'served.log').read_text())[1])
        time.sleep(WARM_UP)
        viewer = Viewer(port)
        for _ in range(args.cycles):
            for watched in (False, True):
                if watched:
                    viewer.connect()
                time.sleep(SETTLE)
                start = time.monotonic()
                time.sleep(args.phase)
                end = time.monotonic()
                received = viewer.received if watched else 0
                if watched:
                    viewer.disconnect()
                phases.append(
                    {
                        'viewer': watched,
                        'viewer_messages_per_s': received / (end - start + SETTLE),
                        **phase_figures(windows, start, end),
                    }
                )
    finally:
        executor.shutdown()
        for process in processes.values():
            process.send_signal(2)
        for process in processes.values():
            process.wait(30)
        rclpy.try_shutdown()
    report(phases, load_start, os.getloadavg(), args)


def report(phases, load_start, load_end, args):
    def ratio(kind, key, node='served'):
        chosen = [p for p in phases if p['viewer'] == kind]
        return statistics.median(p[node][key] / p['plain'][key] for p in chosen)

    figures = {
        'phase_s': args.phase,
        'cycles': args.cycles,
        'load_average_start_end': [load_start[0], load_end[0]],
        'phases': phases,
        'ratio_p50_no_viewer': ratio(False, 'p50_ms'),
        'ratio_p99_no_viewer': ratio(False, 'p99_ms'),
        'ratio_p50_viewer': ratio(True, 'p50_ms'),
        'ratio_p99_viewer': ratio(True, 'p99_ms'),
        'control_ratio_p50': ratio(False, 'p50_ms', 'control'),
        'control_ratio_p99': ratio(False, 'p99_ms', 'control'),
        'control_ratio_p50_viewer': ratio(True, 'p50_ms', 'control'),
        'control_ratio_p99_viewer': ratio(True, 'p99_ms', 'control'),
    }
    print(
        f'{"phase":<8}{"viewer msg/s":>13}'
        + ''.join(f'{name + " p50/p99 ms":>20}' for name in NODES)
        + f'{"late ticks " + "/".join(NODES):>30}'
    )
    for phase in phases:
        print(
            f'{"viewer" if phase["viewer"] else "nobody":<8}'
            f'{phase["viewer_messages_per_s"]:>13.0f}'
            + ''.join(
                f'{phase[name]["p50_ms"]:>11.3f}/{phase[name]["p99_ms"]:<8.3f}' for name in NODES
            )
            + f'{"/".join(str(phase[name]["late_ticks"]) for name in NODES):>30}'
        )
    for kind, label in ((False, 'nobody connected'), (True, 'viewer connected')):
        suffix = '_viewer' if kind else ''
        print(
            f'{label}: served/plain p50 {ratio(kind, "p50_ms"):.3f}, p99 '
            f'{ratio(kind, "p99_ms"):.3f}; control/plain (noise) p50 '
            f'{figures["control_ratio_p50" + suffix]:.3f}, p99 '
            f'{figures["control_ratio_p99" + suffix]:.3f}'
        )
    print(f'load average {load_start[0]:.2f} -> {load_end[0]:.2f}')
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(figures, indent=2))


if __name__ == '__main__':
    sys.exit(main())
