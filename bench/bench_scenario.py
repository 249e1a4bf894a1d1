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
#
# In one run, on a ROS domain of its own (localhost only), each --repeats times, in turn:
#
# - model: valve_node's RealTimeModel advanced tick by tick (1 ms, 100 RK4 steps) in
#   this process, the paper step's flows: the model alone;
# - round trip: a bare rclpy node (on valve_node's executor) that answers each /clock
#   with the two messages that end a tick (applied_inlet_flow, relief_flow), driven by
#   valve_sim.ros.lockstep.Lockstep: the DDS round trip and the driver, the floor any
#   lockstep run here has;
# - lockstep: valve_node alone in lockstep (every tick topic published at 1 kHz, no
#   recorder): model + publishing + round trip;
# - scenario: `scenario run` of scenarios/paper_step.yaml, analyser_node recording
#   every topic: all of it.
#
# Each reports its real-time factor (model time per wall time of the stepping) and
# its wall time per tick; the differences between them say where a scenario's time
# goes. The load average at start and end is printed: the machine is shared.

import argparse
import json
import os
from pathlib import Path
import statistics
import sys
import tempfile
import time

from valve_sim.ros.isolation import claim_domain


REPO = Path(__file__).resolve().parent.parent
SCENARIO = REPO / 'scenarios' / 'paper_step.yaml'
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


def model_alone(scenario):
    """Advance valve_node's RealTimeModel tick by tick with the scenario's flows; wall [s]."""
    from valve_sim.core.parameters import load_parameters
    from valve_sim.core.realtime_model import RealTimeModel

    loaded = load_parameters()
    params, settings = loaded.params, loaded.settings
    flows = scenario.inputs['inlet_flow'].sample(scenario.tick_times())
    model = RealTimeModel(params, settings['step_size'], flows[0])
    model.trial(params, settings['step_size'], flows[0])  # kernels loaded, as the node does
    model.start(0)
    started = time.perf_counter()
    for tick in range(1, scenario.ticks + 1):
        model.advance_to(tick * scenario.period_ns, flows[tick - 1], 10 ** 12)
    return time.perf_counter() - started


def lockstep_run(scenario, command, folder, name):
    """Drive one node process (command) on /clock for the scenario's ticks; wall [s]."""
    import rclpy
    from valve_sim.ros.lockstep import Lockstep
    from valve_sim.ros.node_processes import NodeProcesses

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
        started = time.perf_counter()
        for _ in range(scenario.ticks):
            driver.tick()
        return time.perf_counter() - started
    finally:
        if driver is not None:
            driver.close()
        context.try_shutdown()
        processes.stop()


def scenario_run(scenario, folder):
    """Run the scenario as `valve-sim scenario run` does; its stepping's wall time [s]."""
    from valve_sim.ros.scenario_runner import run_scenario

    record = run_scenario(scenario, folder, progress=lambda text: None)
    assert record.passed, [check.name for check in record.checks if not check.passed]
    return record.wall_s


def summary(walls, scenario):
    wall = statistics.median(walls)
    return {'runs': len(walls), 'median_wall_s': wall, 'walls_s': walls,
            'real_time_factor': scenario.duration / wall,
            'per_tick_ms': wall / scenario.ticks * 1e3}


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3, help='runs of each kind')
    parser.add_argument('--json', type=Path, help='also write the figures as JSON')
    args = parser.parse_args()
    claim_domain(keep_existing=False)
    from valve_sim.analysis.scenario_file import load_scenario
    from valve_sim.ros import node_command

    scenario = load_scenario(SCENARIO)
    valve = node_command('valve_node', parameters={
        'use_sim_time': 'true', 'initial_inlet_flow': repr(scenario.inputs['inlet_flow'].initial)})
    bare = [sys.executable, '-c', BARE_RESPONDER, '--ros-args', '-p', 'use_sim_time:=true']
    print(f'load average at start: {os.getloadavg()}', flush=True)
    walls = {'model': [], 'round_trip': [], 'lockstep': [], 'scenario': []}
    with tempfile.TemporaryDirectory() as temporary:
        for repeat in range(args.repeats):
            folder = Path(temporary) / str(repeat)
            for kind in walls:
                (folder / kind).mkdir(parents=True)
            walls['model'].append(model_alone(scenario))
            walls['round_trip'].append(lockstep_run(scenario, bare, folder / 'round_trip',
                                                    'bare_responder'))
            walls['lockstep'].append(lockstep_run(scenario, valve, folder / 'lockstep',
                                                  'valve_node'))
            walls['scenario'].append(scenario_run(scenario, folder / 'scenario'))
            runs = ', '.join(f'{kind} {values[-1]:.3f} s' for kind, values in walls.items())
            print(f'run {repeat + 1}: {runs}', flush=True)
    results = {kind: summary(values, scenario) for kind, values in walls.items()}
    tick = {kind: result['per_tick_ms'] for kind, result in results.items()}
    results['split_per_tick_ms'] = {
        'model': tick['model'],
        'round_trip_floor': tick['round_trip'],
        'valve_node_publishing_and_executor': tick['lockstep'] - tick['round_trip']
        - tick['model'],
        'analyser_and_runner': tick['scenario'] - tick['lockstep'],
    }
    results['load_average_end'] = os.getloadavg()
    print(f'{scenario.duration:g} s of model time, {scenario.ticks} ticks '
          f'(scenarios/{SCENARIO.name}), median of {args.repeats}:')
    for kind in walls:
        print(f'  {kind:<11} {results[kind]["real_time_factor"]:7.2f}x real time, '
              f'{results[kind]["per_tick_ms"]:.3f} ms a tick')
    print('where a scenario tick goes [ms]: ' + ', '.join(
        f'{name} {value:.3f}' for name, value in results['split_per_tick_ms'].items()))
    print(f'load average at end: {results["load_average_end"]}')
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(results, indent=2) + '\n')


if __name__ == '__main__':
    main()
