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


"""Benchmark the FMU (valve-sim fmu) under FMPy against the offline model, in one run."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_fmu.py [--repeats 5] [--json FILE]
#
# Measured side by side in one process (this machine is shared and noisy, so compare
# the ratios, not the absolute times), each the best of --repeats, the paper's 1.25 s
# step with the reference parameters and the 10 us internal step:
# 1. offline: valve_sim.core.simulation.simulate, recording every 1 ms;
# 2. the FMU under fmpy.simulate_fmu at a 1 ms communication step (the input table and
#    the recorder included, as a user runs it);
# 3. the FMU driven by direct FMI calls (FMPy's FMU2Slave: setReal, doStep, getReal of
#    p_s) at communication steps of 1 ms and 0.1 ms: the cost of one doStep.
# Reported: wall time of each, its ratio to the offline run, the doStep rate and the
# real-time factor (model time / wall time). The FMU is built once, first.
# 4. one doStep of 0.1 s, 1 s and 10 s (10 us internal steps: 1e4 to 1e6 steps) by FMI
#    calls, from the steady state at 20 L/min, against doSteps of 10 ms over the same
#    time (the time grows with the step as theirs does), and the peak of Python's
#    traced memory during the one call (tracemalloc: numpy's arrays included), which
#    must not grow with the step.

import argparse
import json
import math
import tempfile
import time
import tracemalloc

import fmpy
from fmpy.fmi2 import FMU2Slave
import numpy as np
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP as SCENARIO
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import simulate
from valve_sim.fmu.builder import build


def best_time(function, repeats):
    """Return the shortest wall time [s] of repeats calls of function (after one warm-up)."""
    function()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def simulate_fmu(path):
    """Run the paper's step through the FMU with fmpy.simulate_fmu at 1 ms (tank at ambient)."""
    signal = np.array(
        [(0.0, SCENARIO.initial_flow, 0.0), (SCENARIO.step_time, SCENARIO.initial_flow, 0.0),
         (SCENARIO.step_time, SCENARIO.final_flow, 0.0),
         (SCENARIO.end_time, SCENARIO.final_flow, 0.0)],
        dtype=[('time', float), ('inlet_flow', float), ('tank_pressure', float)],
    )
    fmpy.simulate_fmu(str(path), stop_time=SCENARIO.end_time, output_interval=1e-3,
                      input=signal, output=['supply_pressure'])


def direct_calls(folder, description, interval):
    """Return a function that runs the paper's step by FMI calls at interval [s]."""
    refs = {v.name: v.valueReference for v in description.modelVariables}
    steps = round(SCENARIO.end_time / interval)
    step_at = round(SCENARIO.step_time / interval)

    def run():
        fmu = FMU2Slave(guid=description.guid, unzipDirectory=folder,
                        modelIdentifier=description.coSimulation.modelIdentifier,
                        instanceName='bench')
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        fmu.setReal([refs['inlet_flow']], [SCENARIO.initial_flow])
        fmu.exitInitializationMode()
        for k in range(steps):
            flow = SCENARIO.final_flow if k >= step_at else SCENARIO.initial_flow
            fmu.setReal([refs['inlet_flow']], [flow])
            fmu.doStep(currentCommunicationPoint=k * interval, communicationStepSize=interval)
            fmu.getReal([refs['supply_pressure']])
        fmu.terminate()
        fmu.freeInstance()

    return run


def long_steps(folder, description, repeats, lengths=(0.1, 1.0, 10.0), split=0.01):
    """
    Return {length [s]: (wall of one doStep, wall of doSteps of split [s], peak memory [B])}.

    Each from the steady state at 20 L/min, best of repeats; the same model time
    integrated both ways, so equal walls mean a time proportional to the step.
    """
    refs = {v.name: v.valueReference for v in description.modelVariables}
    results = {}
    for length in lengths:
        walls, peak = {1: math.inf, round(length / split): math.inf}, 0
        for steps in [steps for steps in walls for _ in range(repeats)]:
            fmu = FMU2Slave(guid=description.guid, unzipDirectory=folder,
                            modelIdentifier=description.coSimulation.modelIdentifier,
                            instanceName='long')
            fmu.instantiate()
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.setReal([refs['inlet_flow']], [SCENARIO.final_flow])
            fmu.exitInitializationMode()
            tracemalloc.start()
            start = time.perf_counter()
            for k in range(steps):
                fmu.doStep(currentCommunicationPoint=k * length / steps,
                           communicationStepSize=length / steps)
            walls[steps] = min(walls[steps], time.perf_counter() - start)
            if steps == 1:
                peak = max(peak, tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
            fmu.terminate()
            fmu.freeInstance()
        results[length] = (*walls.values(), peak)
    return results


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip())
    parser.add_argument('--repeats', type=int, default=5)
    parser.add_argument('--json', metavar='FILE', help='write the results as JSON')
    args = parser.parse_args()
    loaded = load_parameters()
    params, settings = loaded.params, loaded.settings
    with tempfile.TemporaryDirectory(prefix='bench_fmu_') as folder:
        path = build(f'{folder}/valve.fmu', params, settings)
        unzipped = fmpy.extract(str(path), f'{folder}/unzipped')
        description = fmpy.read_model_description(str(path))
        offline = best_time(
            lambda: simulate(params, SCENARIO, record_interval=1e-3), args.repeats
        )
        runs = {
            'offline simulate (1 ms records)': (offline, None),
            'fmpy.simulate_fmu, 1 ms steps': (
                best_time(lambda: simulate_fmu(path), args.repeats), 1e-3),
            'FMI calls, 1 ms steps': (
                best_time(direct_calls(unzipped, description, 1e-3), args.repeats), 1e-3),
            'FMI calls, 0.1 ms steps': (
                best_time(direct_calls(unzipped, description, 1e-4), args.repeats), 1e-4),
        }
        long = long_steps(unzipped, description, args.repeats)
    results = {}
    print(f"the paper's {SCENARIO.end_time:g} s step, 10 us RK4 steps; best of {args.repeats}")
    print(f'{"run":<34}{"wall [s]":>10}{"/ offline":>11}{"doStep/s":>11}{"x real time":>13}')
    for name, (wall, interval) in runs.items():
        rate = SCENARIO.end_time / interval / wall if interval else None
        results[name] = {'wall_s': wall, 'ratio_to_offline': wall / offline,
                         'do_steps_per_s': rate, 'real_time_factor': SCENARIO.end_time / wall}
        print(f'{name:<34}{wall:>10.4f}{wall / offline:>11.2f}'
              + (f'{rate:>11.0f}' if rate else f'{"-":>11}')
              + f'{SCENARIO.end_time / wall:>13.1f}')
    print(f'{"model time [s]":<20}{"one doStep [s]":>16}{"10 ms doSteps [s]":>19}'
          f'{"ratio":>8}{"peak memory":>14}')
    for length, (one, split, peak) in long.items():
        results[f'one doStep of {length:g} s'] = {
            'wall_s': one, 'wall_10ms_steps_s': split, 'peak_traced_bytes': peak}
        print(f'{length:<20g}{one:>16.3f}{split:>19.3f}{one / split:>8.2f}{peak / 1e3:>11.0f} kB')
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(results, stream, indent=2)


if __name__ == '__main__':
    main()
