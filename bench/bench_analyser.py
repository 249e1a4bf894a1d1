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

"""Benchmark analyser_node recording all valve topics at 1 kHz, beside a bare rclpy subscriber."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_analyser.py [--duration 60] [--json FILE]
#
# One run, three processes on this machine's DDS (a ROS_DOMAIN_ID of its own,
# discovery on localhost):
# - this script publishes valve_node's six tick topics at 1 kHz (valve_sim.ros.replay)
#   for --duration seconds: a simulated 5 <-> 20 L/min step every 1.25 s, so the
#   analyser also measures a step every 1.25 s;
# - analyser_node records them (and everything else it records by default) to MCAP;
# - a bare subscriber counts the same six topics through rclpy's executor
#   (raw callbacks, the same reliable QoS and --queue-depth), doing nothing else.
# Reported: messages published against recorded (analyser) and counted (bare
# subscriber), each process's CPU share of one core over the publishing time,
# the analyser's write throughput, and resident memory after 10 s and at the end
# (target: none lost, memory flat).

import argparse
import json
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import psutil
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, simulate, Waveforms
from valve_sim.ros.isolation import claim_domain


PERIOD = 1e-3  # [s] tick period, valve_node's default
EARLY_RSS_TIME = 10.0  # [s] after the start of publishing
SETTLE_TIME = 3.0  # [s] after publishing, before the subscribers are stopped
LOW, HIGH = 5.0 * LITRE_PER_MINUTE, 20.0 * LITRE_PER_MINUTE


def step_cycle(params):
    """
    Return the waveforms of one 2.5 s cycle at 1 kHz.

    Up 5 -> 20 L/min at 0, down at 1.25 s (each step's last sample).
    """
    up = simulate(
        params, FlowStep(LOW, HIGH, step_time=0.0, end_time=1.25), record_interval=PERIOD
    )
    down = simulate(
        params, FlowStep(HIGH, LOW, step_time=0.0, end_time=1.25), record_interval=PERIOD
    )
    return Waveforms(
        np.concatenate([up.time[1:], 1.25 + down.time[1:]]),
        np.vstack([up.states[1:], down.states[1:]]),
        np.concatenate([up.inlet_flow[1:], down.inlet_flow[1:]]),
    )


def repeated(cycle, duration):
    """Repeat cycle to cover duration [s], time continuous."""
    count = int(np.ceil(duration / cycle.time[-1]))
    length = len(cycle.time)
    ticks = int(round(duration / PERIOD))
    time_axis = (np.arange(count * length) + 1) * PERIOD
    return Waveforms(
        time_axis[:ticks],
        np.tile(cycle.states, (count, 1))[:ticks],
        np.tile(cycle.inlet_flow, count)[:ticks],
    )


def count_only(queue_depth):
    """
    Run the bare subscriber: count the tick topics in raw callbacks until SIGINT.

    Then print the counts as JSON.
    """
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from valve_sim.recording.valve_topics import message_class, TICK_TOPICS, TOPIC_TYPES

    rclpy.init()
    node = rclpy.create_node('bare_counter')
    counts = dict.fromkeys(TICK_TOPICS, 0)
    queue = QoSProfile(depth=queue_depth, reliability=ReliabilityPolicy.RELIABLE)
    for topic in TICK_TOPICS:

        def count(_, topic=topic):
            counts[topic] += 1

        node.create_subscription(message_class(TOPIC_TYPES[topic]), topic, count, queue, raw=True)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    print(json.dumps(counts), flush=True)


class Sampler(threading.Thread):
    """CPU time and RSS of processes: at start(), EARLY_RSS_TIME later, and at finish()."""

    def __init__(self, processes):
        super().__init__(daemon=True)
        self.processes = {
            **{name: psutil.Process(p.pid) for name, p in processes.items()},
            'publisher (this)': psutil.Process(),
        }
        self.early_rss = {}
        self.started = time.monotonic()
        self.cpu_start = {name: sum(p.cpu_times()[:2]) for name, p in self.processes.items()}

    def run(self):
        time.sleep(EARLY_RSS_TIME)
        self.early_rss = {name: p.memory_info().rss for name, p in self.processes.items()}

    def finish(self):
        elapsed = time.monotonic() - self.started
        return elapsed, {
            name: {
                'cpu_share': (sum(p.cpu_times()[:2]) - self.cpu_start[name]) / elapsed,
                'rss_early_mb': self.early_rss.get(name, float('nan')) / 2**20,
                'rss_end_mb': p.memory_info().rss / 2**20,
            }
            for name, p in self.processes.items()
        }


def recorded_counts(bag):
    from mcap.reader import make_reader

    with open(bag, 'rb') as stream:
        summary = make_reader(stream).get_summary()
    return {
        summary.channels[cid].topic.lstrip('/'): n
        for cid, n in summary.statistics.channel_message_counts.items()
    }


def run_processes(folder, waveforms, queue_depth):
    """
    Publish waveforms to analyser_node (recording into folder) and the bare subscriber.

    Returns the figures as a dict.
    """
    import rclpy
    from valve_sim.ros.replay import Replay
    from valve_sim.ros import node_command

    processes = {
        'analyser_node': subprocess.Popen(
            node_command(
                'analyser_node', parameters={'output_dir': folder, 'queue_depth': queue_depth}
            ),
            stderr=subprocess.DEVNULL,
        ),
        'bare subscriber': subprocess.Popen(
            [sys.executable, __file__, '--count-only', '--queue-depth', str(queue_depth)],
            stdout=subprocess.PIPE,
        ),
    }
    rclpy.init()
    replay = Replay(rclpy.create_node('bench_publisher'))
    replay.wait_for_subscribers(count=len(processes))
    time.sleep(1.0)  # both subscribers matched: let discovery traffic settle
    sampler = Sampler(processes)
    sampler.start()
    replay.publish(waveforms, time.time_ns(), PERIOD, every=1)
    elapsed, usage = sampler.finish()
    time.sleep(SETTLE_TIME)
    for process in processes.values():
        process.send_signal(signal.SIGINT)
    counted = json.loads(processes['bare subscriber'].communicate(timeout=30)[0])
    processes['analyser_node'].wait(timeout=30)
    rclpy.try_shutdown()
    bag = next(folder.glob('*.mcap'))
    recorded, published = recorded_counts(bag), sum(replay.published.values())
    return {
        'duration_s': elapsed,
        'published': published,
        'recorded': sum(recorded.get(topic, 0) for topic in replay.published),
        'counted_by_bare_subscriber': sum(counted.values()),
        'lost_by_analyser': {
            t: n - recorded.get(t, 0)
            for t, n in replay.published.items()
            if n != recorded.get(t, 0)
        },
        'steps_measured': len(json.loads(bag.with_suffix('.measures.json').read_text())['steps']),
        'bag_mb': bag.stat().st_size / 2**20,
        'write_throughput_mb_s': bag.stat().st_size / 2**20 / elapsed,
        'messages_per_s': published / elapsed,
        'processes': usage,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        '--duration', type=float, default=60.0, help='publishing time [s] (default 60)'
    )
    parser.add_argument(
        '--queue-depth',
        type=int,
        default=1000,
        help="subscription queue of both subscribers [messages] (default 1000, the analyser's)",
    )
    parser.add_argument('--json', metavar='FILE', help='also write the figures as JSON')
    parser.add_argument('--count-only', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.count_only:
        return count_only(args.queue_depth)
    claim_domain()  # ROS_DOMAIN_ID if set, else one no other run holds; discovery on localhost
    from valve_sim.core.parameters import load_parameters

    waveforms = repeated(step_cycle(load_parameters().params), args.duration)
    with tempfile.TemporaryDirectory(prefix='bench_analyser_') as folder:
        figures = run_processes(Path(folder), waveforms, args.queue_depth)
    published, elapsed = figures['published'], figures['duration_s']
    print(
        f'published {published} messages in {elapsed:.1f} s ({published / elapsed:.0f} msg/s); '
        f'analyser recorded {figures["recorded"]} '
        f'(lost: {figures["lost_by_analyser"] or "none"}), '
        f'bare subscriber counted {figures["counted_by_bare_subscriber"]}; '
        f'{figures["steps_measured"]} steps measured'
    )
    print(
        f'analyser wrote {figures["bag_mb"]:.1f} MiB: {figures["write_throughput_mb_s"]:.2f} MiB/s'
    )
    print(f'{"process":<18}{"CPU share":>10}{"RSS 10 s":>11}{"RSS end":>10}')
    for name, figure in figures['processes'].items():
        print(
            f'{name:<18}{figure["cpu_share"]:>9.0%} {figure["rss_early_mb"]:>8.1f} MiB'
            f'{figure["rss_end_mb"]:>6.1f} MiB'
        )
    if args.json:
        Path(args.json).write_text(json.dumps(figures, indent=2) + '\n')


if __name__ == '__main__':
    main()
