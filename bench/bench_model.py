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

"""Benchmark of the model core: the paper's 1.25 s run and the parameter study."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_model.py [--repeats 5] [--json FILE]
#
# Measured side by side in one run (this machine is shared and noisy, so compare
# the ratios, not the absolute times):
# 1. Fixed-step RK4 at 10 us (our kernel, one core) against real time.
# 2. scipy.integrate.solve_ivp, LSODA and Radau, on the same right-hand side
#    (valve_sim.core.model.derivatives), at matched accuracy. Error measure: the
#    largest deviation of p_s from a reference run (RK4 at 1.25 us), sampled every
#    0.1 ms over the whole run, relative to the overshoot p_1 - p_0. For each
#    solver the loosest rtol (atol scaled per state) whose error is no larger than
#    RK4's at 10 us is used.
# 3. The full parameter study (valve-sim study: 26 distinct runs of the 31 cases),
#    on all cores, through the study runner: on a local Dask cluster (its start-up
#    timed apart) and on a local process pool (the fallback without dask), then
#    the whole command (cluster start, runs, CSV, figures).
# Targets (issue 2): the single run >= 50x faster than real time and faster than
# solve_ivp; the study < 15 s on 2 cores.

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from scipy.integrate import solve_ivp
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP as SCENARIO
from valve_sim.analysis.studies.backend import DaskBackend, PoolBackend
from valve_sim.analysis.studies.cases import run_all
from valve_sim.core.coefficients import coefficients
from valve_sim.core.model import P_S, state_derivative
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import simulate
from valve_sim.core.steady_state import steady_state


SAMPLE = 1e-4  # [s] comparison grid
STATE_SCALE = np.array([1e6] * 4 + [1e-4, 1e-2, 1e-5, 1e-2])  # atol per state = rtol * scale


def best_time(function, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def rk4_supply_pressure(params, step):
    return simulate(params, SCENARIO, step, SAMPLE)['supply_pressure']


def solve_ivp_supply_pressure(params, method, rtol):
    """p_s on the SAMPLE grid, integrating each constant-flow segment separately."""
    c = coefficients(params)
    state = steady_state(params, SCENARIO.initial_flow)
    grid = np.arange(0.0, SCENARIO.end_time + SAMPLE / 2, SAMPLE)
    pressure = []
    for t0, t1, flow in (
        (0.0, SCENARIO.step_time, SCENARIO.initial_flow),
        (SCENARIO.step_time, SCENARIO.end_time, SCENARIO.final_flow),
    ):
        points = grid[(grid >= t0 - 1e-12) & (grid <= t1 + 1e-12)]
        if pressure:
            points = points[1:]
        solution = solve_ivp(
            lambda t, y: state_derivative(y, flow, c),
            (t0, t1),
            state,
            method=method,
            t_eval=points,
            rtol=rtol,
            atol=rtol * STATE_SCALE,
        )
        if not solution.success:
            raise RuntimeError(f'{method} failed: {solution.message}')
        pressure.append(solution.y[P_S])
        state = solution.y[:, -1]
    return np.concatenate(pressure)


def error_of(pressure, reference, overshoot):
    return float(np.max(np.abs(pressure - reference)) / overshoot)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=5)
    parser.add_argument('--json', metavar='FILE', help='also write the results as JSON')
    args = parser.parse_args()
    params = load_parameters().params

    rk4_supply_pressure(params, 1e-5)  # compile (numba cache) and warm up
    reference = rk4_supply_pressure(params, 1.25e-6)
    index = int(round(SCENARIO.step_time / SAMPLE))
    overshoot = reference.max() - reference[index]
    rk4_time, pressure = best_time(lambda: rk4_supply_pressure(params, 1e-5), args.repeats)
    rk4_error = error_of(pressure, reference, overshoot)
    rows = [
        {'method': 'RK4 10 us (valve_sim)', 'seconds': rk4_time, 'error': rk4_error, 'rtol': None}
    ]

    for method in ('LSODA', 'Radau'):
        for rtol in (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10):
            pressure = solve_ivp_supply_pressure(params, method, rtol)
            error = error_of(pressure, reference, overshoot)
            if error <= rk4_error:
                break
        seconds, _ = best_time(
            lambda: solve_ivp_supply_pressure(params, method, rtol), max(1, args.repeats // 2)
        )
        rows.append(
            {
                'method': f'solve_ivp {method}',
                'seconds': seconds,
                'error': error,
                'rtol': rtol,
                'matched': error <= rk4_error,
            }
        )

    cores = os.cpu_count() or 1
    with tempfile.TemporaryDirectory() as out:
        startup_seconds, dask = best_time(lambda: DaskBackend(None, cores).start(), 1)
        try:
            study_seconds, _ = best_time(
                lambda: run_all(params, 1e-5, dask, f'{out}/dask.jsonl', progress_stream=None), 1
            )
        finally:
            dask.close()
        pool_seconds, _ = best_time(
            lambda: run_all(
                params, 1e-5, PoolBackend(cores), f'{out}/pool.jsonl', progress_stream=None
            ),
            1,
        )
        command_seconds, _ = best_time(
            lambda: subprocess.run(
                [sys.executable, '-m', 'valve_sim.commands.cli', 'study', '--out', out],
                check=True,
                capture_output=True,
            ),
            1,
        )

    print(
        f"paper's run: {SCENARIO.end_time} s of model time; "
        'error = max|p_s - p_s,ref| / (p_1 - p_0), '
        f'reference RK4 1.25 us'
    )
    print(
        f'{"method":<24}{"rtol":>8}{"error":>11}{"wall [ms]":>11}'
        f'{"x real time":>13}{"x vs RK4":>10}'
    )
    for row in rows:
        rtol = f'{row["rtol"]:.0e}' if row['rtol'] else '-'
        note = (
            '' if row.get('matched', True) else "  (tightest rtol tried; RK4's error not reached)"
        )
        print(
            f'{row["method"]:<24}{rtol:>8}{row["error"]:>11.2e}{row["seconds"] * 1e3:>11.1f}'
            f'{SCENARIO.end_time / row["seconds"]:>13.1f}{row["seconds"] / rk4_time:>10.1f}{note}'
        )
    print(
        f'parameter study, 26 runs on {cores} cores: local Dask cluster {study_seconds:.2f} s '
        f'(+ {startup_seconds:.2f} s to start it), process pool {pool_seconds:.2f} s; '
        'the whole `valve-sim study` command with CSV and figures: '
        f'{command_seconds:.2f} s (target < 15 s)'
    )
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(
                {
                    'runs': rows,
                    'study_seconds': study_seconds,
                    'study_cluster_start_seconds': startup_seconds,
                    'study_pool_seconds': pool_seconds,
                    'study_command_seconds': command_seconds,
                    'cores': cores,
                },
                stream,
                indent=2,
            )


if __name__ == '__main__':
    main()
