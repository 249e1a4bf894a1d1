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
Benchmark valve_simulator's stepping through simulation_interfaces, three ways side by side.

    .venv/bin/python bench/bench_simulator.py [--ticks 2000] [--json out/bench_simulator.json]

One valve_simulator (scenarios/paper_step.yaml), paused; then, in one run, each for
--ticks ticks: StepSimulation(steps=N) in one call (10 ticks per /clock), N calls of
StepSimulation(steps=1) (a round trip per tick, as a client that acts every tick),
and the SimulateSteps action (a tick per /clock, feedback after each). Prints ticks per
second and model time over wall time (1 kHz ticks: ticks/s / 1000) for each, and the
load average, so ratios are read side by side, never as absolute targets.
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time


REPO = Path(__file__).resolve().parent.parent
TIMEOUT = 600.0  # [s] for a call (a loaded machine)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--ticks', type=int, default=2000, help='ticks per way (default 2000)')
    parser.add_argument('--json', type=Path, default=REPO / 'out' / 'bench_simulator.json')
    options = parser.parse_args()

    from valve_sim.ros.isolation import claim_domain

    claim_domain()
    import rclpy
    import rclpy.executors
    from rclpy.action import ActionClient
    from simulation_interfaces.action import SimulateSteps
    from simulation_interfaces.msg import Result, SimulationState
    from simulation_interfaces.srv import SetSimulationState, StepSimulation

    folder = Path(tempfile.mkdtemp(prefix='bench_simulator_'))
    with open(folder / 'simulator.log', 'w') as log:
        process = subprocess.Popen(
            [sys.executable, '-m', 'valve_sim.ros.simulation_server',
             str(REPO / 'scenarios' / 'paper_step.yaml'), '--output-dir', str(folder)],
            stdout=log, stderr=subprocess.STDOUT)
    rclpy.init()
    node = rclpy.create_node('bench_simulator')
    # an executor of its own: rclpy.spin_until_future_complete(node, ...) adds the node to
    # the global executor and removes it again on every call, about 30 ms at load 15
    executor = rclpy.executors.SingleThreadedExecutor()
    executor.add_node(node)

    clients = {}

    def call(kind, name, request):
        if name not in clients:
            clients[name] = node.create_client(kind, f'/valve_simulator/{name}')
            assert clients[name].wait_for_service(timeout_sec=TIMEOUT), name
        future = clients[name].call_async(request)
        executor.spin_until_future_complete(future, timeout_sec=TIMEOUT)
        assert future.done(), f'{name}: no answer within {TIMEOUT:g} s'
        return future.result()

    def step(count):
        done = call(StepSimulation, 'step_simulation', StepSimulation.Request(steps=count))
        assert done.result.result == Result.RESULT_OK, done.result.error_message

    def action_steps(count):
        goal = action.send_goal_async(SimulateSteps.Goal(steps=count))
        executor.spin_until_future_complete(goal, timeout_sec=TIMEOUT)
        result = goal.result().get_result_async()
        executor.spin_until_future_complete(result, timeout_sec=TIMEOUT)
        assert result.result().result.result.result == Result.RESULT_OK

    try:
        pause = SimulationState(state=SimulationState.STATE_PAUSED)
        call(SetSimulationState, 'set_simulation_state', SetSimulationState.Request(state=pause))
        action = ActionClient(node, SimulateSteps, '/valve_simulator/simulate_steps')
        assert action.wait_for_server(timeout_sec=TIMEOUT)
        step(10)  # warm: the first calls
        ways = {
            'StepSimulation(N), one call': lambda: step(options.ticks),
            'StepSimulation(1), N calls': lambda: [step(1) for _ in range(options.ticks)],
            'SimulateSteps(N) action': lambda: action_steps(options.ticks),
        }
        results = {}
        for name, run in ways.items():
            started = time.perf_counter()
            run()
            wall = time.perf_counter() - started
            results[name] = {'wall_s': wall, 'ticks_per_s': options.ticks / wall}
            print(f'{name:30s} {options.ticks / wall:8.0f} ticks/s  '
                  f'{options.ticks / 1000 / wall:6.2f}x real time', flush=True)
        results['load_average'] = os.getloadavg()
        print(f'load average: {results["load_average"]}')
        options.json.parent.mkdir(parents=True, exist_ok=True)
        options.json.write_text(json.dumps(results, indent=2))
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
        process.terminate()
        process.wait(TIMEOUT)


if __name__ == '__main__':
    main()
