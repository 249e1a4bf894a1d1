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
What the node benchmarks share: their processes, the timer floor, options and output.

Run as a script, it is the timer floor: python bench/common.py FILE (see
run_timer_floor).
"""

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import time


REPO = Path(__file__).resolve().parent.parent
PERIOD_NS = 1_000_000  # [ns] the tick period at 1 kHz
SAMPLE_TICKS = 10  # the timer floor notes its counts, stamped, every this many ticks
STEAL = 7  # /proc/stat cpu columns: user nice system idle iowait irq softirq steal ...


def arguments(doc, json_name, duration_help, executor_help="valve_node's executor"):
    """
    Return an ArgumentParser with --duration [s] (default 60), --json and --executor.

    doc: the benchmark's docstring, whose first line is the description; --json
    defaults to out/json_name; --executor is a valve_node executor, by default
    valve_node's.
    """
    from valve_sim.ros.spinning import DEFAULT_EXECUTOR, EXECUTORS

    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument(
        '--duration', type=float, default=60.0, help=f'{duration_help} [s] (default 60)'
    )
    parser.add_argument(
        '--json', type=Path, default=REPO / 'out' / json_name, help='JSON output file'
    )
    parser.add_argument(
        '--executor',
        choices=EXECUTORS,
        default=DEFAULT_EXECUTOR,
        help=f'{executor_help} (default {DEFAULT_EXECUTOR})',
    )
    return parser


def add_receive_threads_option(parser):
    """Add --receive-threads: valve_node's option of that name, by default valve_node's."""
    from valve_sim.ros.receive_threads import DEFAULT_POLICY, POLICIES

    parser.add_argument(
        '--receive-threads',
        choices=POLICIES,
        default=DEFAULT_POLICY,
        help=f"valve_node's --receive-threads (default {DEFAULT_POLICY})",
    )


def isolated_environment():
    """
    Claim a ROS domain of this run's own (discovery on localhost); return the child env.

    The children import valve_sim from this checkout; this process's environment gets
    the same settings.
    """
    from valve_sim.ros.isolation import claim_domain

    claim_domain(keep_existing=False)
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get('PYTHONPATH')])),
    )
    os.environ.update(env)
    return env


def write_figures(figures, table, path):
    """Print the table and write the figures as JSON to path."""
    print(table)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(figures, indent=2, default=float) + '\n')
    print(f'figures written to {path}')


def run_benchmark(args, helpers, measure, table):
    """
    Run a benchmark on its parsed command line args; return the exit code.

    args: from an arguments() parser with the benchmark's own options. helpers:
    {dest: run} for the hidden options by which a benchmark starts itself as a helper
    process (the flood publisher, the echo node): when args has one, run(value) is
    all this process does. Otherwise measure(args, env) measures, its child processes
    started with env (a ROS domain of this run's own, isolated_environment), and the
    figures it returns are printed as table(figures) and written to args.json.
    """
    for dest, run in helpers.items():
        value = getattr(args, dest)
        if value:
            return run(value)
    figures = measure(args, isolated_environment())
    write_figures(figures, table(figures), args.json)
    return 0


def start(command, env):
    return subprocess.Popen(command, env=env, cwd=REPO)


def stop(process):
    """SIGINT the process and return its exit code (killed after 30 s)."""
    process.send_signal(signal.SIGINT)
    try:
        return process.wait(timeout=30)
    except subprocess.TimeoutExpired:
        process.kill()
        return process.wait()


class TimerFloor:
    """
    The timer floor in its own process, from construction until stop().

    scheduler: a command prefix such as chrt; flooded: None, or the loop's process
    also subscribes to inlet_flow as valve_node does (never taking a message), its
    receive threads under this valve_node --receive-threads policy, so that a flood
    costs it the middleware's receiving too.
    """

    def __init__(self, env, scheduler=(), flooded=None):
        self.path = REPO / 'out' / f'timer_floor_{os.getpid()}_{time.monotonic_ns()}.json'
        self.path.parent.mkdir(exist_ok=True)
        command = [*scheduler, sys.executable, __file__, str(self.path)]
        self.process = start(command + (['--flooded', flooded] if flooded else []), env)
        self.exit_code = None

    def stop(self, window=None):
        """
        Stop it; return {ticks, late, missed, on_time_percent}.

        window: None (counted from start to stop) or (start, end) [ns, system clock]:
        counted between the floor's last notes before start and before end (at most
        SAMPLE_TICKS ticks early), to compare with a node's counters stamped so.
        """
        self.exit_code = stop(self.process)
        written = json.loads(self.path.read_text())
        self.path.unlink()
        counts = {key: written[key] for key in ('ticks', 'late', 'missed')}
        if window is not None:
            first, last = (_last_note_before(written['notes'], moment) for moment in window)
            counts = {key: last[key] - first[key] for key in counts}
        return {**counts, 'on_time_percent': on_time_percent(**counts)}


def _last_note_before(notes, moment):
    """Return the counts {ticks, late, missed} of the last of notes stamped before moment."""
    earlier = [note for note in notes if note[0] <= moment]  # notes are in time order
    _, ticks, late, missed = earlier[-1] if earlier else notes[0]
    return {'ticks': ticks, 'late': late, 'missed': missed}


def run_timer_floor(path, flooded=None):
    """
    Run the timer floor: a bare Python loop sleeping to 1 kHz slots.

    Its ticks are counted by valve_node's own counting (NodeStatus.tick_started).
    Runs until SIGINT or SIGTERM, then writes {ticks, late, missed, notes} as JSON to
    path; notes: [system clock time [ns], ticks, late, missed] every SAMPLE_TICKS ticks.
    A tick is late if it starts more than LATE_FRACTION of a period after its slot;
    slots that passed while it was late are missed (the loop goes on at the next slot).
    flooded: None, or first subscribe to inlet_flow with valve_node's default QoS
    and put the receive threads under this --receive-threads policy, as valve_node
    does; the middleware receives every message into it, the loop never takes one.
    """
    from valve_sim.ros.node_status import NodeStatus

    if flooded:
        import rclpy
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import Float64
        from valve_sim.ros.receive_threads import ReceiveThreads
        from valve_sim.ros.valve_inputs import INLET_FLOW_QOS

        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        node = rclpy.create_node('flooded_timer_floor')
        qos = INLET_FLOW_QOS['best_effort']
        node.create_subscription(Float64, 'inlet_flow', lambda _: None, qos)
        ReceiveThreads(flooded).update()
    stopped = []
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stopped.append(number))
    status = NodeStatus(0)
    counters = status.counters
    notes = []
    slot = time.monotonic_ns() + PERIOD_NS
    status.previous_slot_ns = slot - PERIOD_NS  # so the first tick is due at slot
    while not stopped:
        delay = slot - time.monotonic_ns()
        if delay > 0:
            time.sleep(delay / 1e9)
        now = time.monotonic_ns()
        newest_slot = slot + (now - slot) // PERIOD_NS * PERIOD_NS
        status.tick_started(now, newest_slot, PERIOD_NS)
        counters.ticks += 1
        slot = newest_slot + PERIOD_NS
        if counters.ticks % SAMPLE_TICKS == 0:
            notes.append(
                (time.time_ns(), counters.ticks, counters.late_ticks, counters.missed_ticks)
            )
    Path(path).write_text(
        json.dumps(
            {
                'ticks': counters.ticks,
                'late': counters.late_ticks,
                'missed': counters.missed_ticks,
                'notes': notes,
            }
        )
    )


class HostSteal:
    """
    The share of CPU time the hypervisor gave to other guests, from construction to percent().

    Read from /proc/stat's steal column (Linux; None elsewhere). A VM's figures move
    with it: a tick the host stalls is late in the node and in the floor alike.
    """

    def __init__(self):
        self._start = _cpu_times()

    def percent(self):
        """Return steal time as a percentage of all CPU time since construction, or None."""
        end = _cpu_times()
        if self._start is None or end is None:
            return None
        total = sum(end) - sum(self._start)
        return 100.0 * (end[STEAL] - self._start[STEAL]) / total if total else 0.0


def steal_text(percent):
    """Return HostSteal.percent() for a table: 'x.xx % of the CPU time' or 'unknown'."""
    return 'unknown (no /proc/stat)' if percent is None else f'{percent:.2f} % of the CPU time'


def _cpu_times():
    try:
        fields = Path('/proc/stat').read_text().split('\n', 1)[0].split()[1:]
    except OSError:
        return None
    return [int(field) for field in fields[: STEAL + 1]]


def on_time_percent(ticks, late, missed):
    """On-time ticks as valve_node's diagnostics count them: (ticks - late) / (ticks + missed)."""
    return 100.0 * (ticks - late) / (ticks + missed) if ticks + missed else float('nan')


if __name__ == '__main__':
    path, *flooded = sys.argv[1:]  # FILE [--flooded POLICY]
    sys.exit(run_timer_floor(path, flooded=flooded[1] if flooded else None))
