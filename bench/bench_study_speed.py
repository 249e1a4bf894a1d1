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

"""Benchmark of study runs: single runs, the batched fast path, and 10,000 runs on Dask."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_study_speed.py [--runs 10000] [--workers N] [--json FILE]
#
# Measured side by side in one run (the machine is shared: compare the ratios; CPU
# seconds of this process are given beside wall seconds for the one-core parts):
# 1. single: the per-run path studies used before issue 12, simulate() (the whole
#    1.25 s with rk4_steps) + step_measures, one run after another on one core.
#    cores / (its seconds per run) is the single-run rate x cores.
# 2. batch: the same parameter sets through simulate_batch (the lanes kernel, the
#    steady lead held) + step_measures, on one core.
# 3. study: --runs cases of the paper's scenario (the six study parameters
#    sampled uniformly within +-10 %, seeded; each valve preset to 7 MPa as the
#    study protocol does) through the study runner on a local Dask cluster of
#    --workers single-threaded processes: end to end, from starting the cluster to
#    the last row on disk. Target (issue 12): 10,000 runs in <= 90 s on 2 cores.
# Reported: seconds, runs per second, and study rate / (single-run rate x cores).

import argparse
import json
import os
from pathlib import Path
import tempfile
import time

import numpy as np
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP as SCENARIO, STUDY_PARAMETERS
from valve_sim.analysis.steps.measures import step_measures
from valve_sim.analysis.studies.backend import DaskBackend
from valve_sim.analysis.studies.cases import StudyCase
from valve_sim.analysis.studies.runner import evaluate_batch, run_cases
from valve_sim.core.batch import simulate_batch
from valve_sim.core.parameters import load_parameters, scaled
from valve_sim.core.simulation import simulate
from valve_sim.core.steady_state import cracking_pressure, with_preset_pressure


SPREAD = 10.0  # [%] uniform half-width of each of the six study parameters


def sampled_params(params, count, seed):
    """Sample count parameter sets: the six study parameters uniform within +-SPREAD %."""
    rng = np.random.default_rng(seed)
    changes = rng.uniform(-SPREAD, SPREAD, size=(count, len(STUDY_PARAMETERS)))
    return [scaled(params, dict(zip(STUDY_PARAMETERS, row))) for row in changes]


def measure(waveforms):
    return step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        SCENARIO.step_time,
    ).values


def timed(function):
    wall, cpu = time.perf_counter(), time.process_time()
    result = function()
    return time.perf_counter() - wall, time.process_time() - cpu, result


def single_path(params_list):
    return [measure(simulate(params, SCENARIO)) for params in params_list]


def batch_path(params_list):
    return [measure(result.waveforms) for result in simulate_batch(params_list, SCENARIO)]


def packed_instructions():
    """
    Count rk4_lanes' vector instructions: {instruction: count} on 4- or 8-double registers.

    Compiled afresh from its source (numba does not show the machine code of a kernel
    loaded from its disk cache), for the signature simulate_batch used.
    """
    import re

    from numba import njit
    from valve_sim.core import lanes

    signature = lanes.rk4_lanes.signatures[0]
    fresh = njit(nogil=True, error_model='numpy')(lanes.rk4_lanes.py_func)
    fresh.compile(signature)
    packed = r'\b(v(?:sqrt|div|mul|add|sub)pd)\s[^\n]*%[yz]mm'
    found = re.findall(packed, fresh.inspect_asm(signature))
    return {name: found.count(name) for name in sorted(set(found))}


def _process_cpu_seconds():
    import psutil

    times = psutil.Process().cpu_times()
    return times.user + times.system


def study(params_list, preset, workers, out):
    """Run the cases on a local Dask cluster; returns (rows, CPU seconds of the workers)."""
    cases = [
        StudyCase(index, params, preset, SCENARIO, 1e-5)
        for index, params in enumerate(params_list)
    ]
    backend = DaskBackend(workers=workers)
    try:
        before = backend.client.run(_process_cpu_seconds)
        rows, _ = run_cases(
            cases,
            Path(out) / 'results.jsonl',
            backend,
            evaluate=evaluate_batch,
            progress_stream=None,
        )
        after = backend.client.run(_process_cpu_seconds)
    finally:
        backend.close()
    return rows, sum(after[worker] - before.get(worker, 0.0) for worker in after)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--runs', type=int, default=10000, help='runs of the Dask study')
    parser.add_argument('--single', type=int, default=32, help='runs timed one by one')
    parser.add_argument('--workers', type=int, default=os.cpu_count() or 1)
    parser.add_argument('--seed', type=int, default=12)
    parser.add_argument('--json', metavar='FILE', help='also write the results as JSON')
    parser.add_argument(
        '--simd',
        action='store_true',
        help='also compile rk4_lanes afresh (about a minute) and count its vector instructions',
    )
    args = parser.parse_args()
    reference = load_parameters().params
    preset = cracking_pressure(reference)
    sample = [with_preset_pressure(p, preset) for p in sampled_params(reference, args.single, 1)]
    batch_path(sample[:2])  # compile (numba cache) and warm up both paths
    single_path(sample[:1])
    single_wall, single_cpu, single = timed(lambda: single_path(sample))
    batch_wall, batch_cpu, batch = timed(lambda: batch_path(sample))
    differences = [
        abs(b[name] - a[name]) / abs(a[name])
        for a, b in zip(single, batch)
        for name in a
        if a[name] not in (None, 0.0) and b[name] is not None
    ]
    cases = sampled_params(reference, args.runs, args.seed)
    with tempfile.TemporaryDirectory() as out:
        study_wall, client_cpu, (rows, worker_cpu) = timed(
            lambda: study(cases, preset, args.workers, out)
        )
    failed = sum(1 for row in rows.values() if row['error'])
    per_single = single_wall / args.single
    floor_rate = args.workers / per_single
    study_rate = args.runs / study_wall
    result = {
        'cores': os.cpu_count(),
        'workers': args.workers,
        'single_run_s': per_single,
        'single_run_cpu_s': single_cpu / args.single,
        'batch_run_s': batch_wall / args.single,
        'batch_run_cpu_s': batch_cpu / args.single,
        'batch_vs_single_cpu': single_cpu / batch_cpu,
        'largest_relative_measure_difference': max(differences),
        'study_runs': args.runs,
        'study_s': study_wall,
        'study_runs_per_s': study_rate,
        'single_rate_x_cores_per_s': floor_rate,
        'study_rate_over_single_rate_x_cores': study_rate / floor_rate,
        'study_failed_runs': failed,
        'study_worker_cpu_s': worker_cpu,
        'study_client_and_scheduler_cpu_s': client_cpu,
        'study_cpu_per_run_s': (worker_cpu + client_cpu) / args.runs,
        'load_average': os.getloadavg(),
    }
    print(
        f'single-run path (simulate 1.25 s + measures): {per_single * 1e3:.1f} ms/run wall, '
        f'{result["single_run_cpu_s"] * 1e3:.1f} ms CPU'
    )
    print(
        f'batch path (simulate_batch + measures):        {result["batch_run_s"] * 1e3:.1f} ms/run '
        f'wall, {result["batch_run_cpu_s"] * 1e3:.1f} ms CPU '
        f'({result["batch_vs_single_cpu"]:.2f}x less CPU; measures differ by at most '
        f'{max(differences):.1e} relative)'
    )
    print(
        f'study: {args.runs} runs on a local Dask cluster of {args.workers} workers: '
        f'{study_wall:.1f} s end to end ({study_rate:.0f} runs/s, {failed} without measures; '
        'target <= 90 s for 10,000)'
    )
    print(
        f'single-run rate x {args.workers} cores: {floor_rate:.0f} runs/s; '
        f'study rate / that: {result["study_rate_over_single_rate_x_cores"]:.2f}'
    )
    print(
        f'study CPU: workers {worker_cpu:.1f} s + client and scheduler {client_cpu:.1f} s = '
        f'{result["study_cpu_per_run_s"] * 1e3:.1f} ms per run; on {args.workers} otherwise '
        f'idle cores that is {(worker_cpu + client_cpu) / args.workers:.1f} s of computing'
    )
    print(f'load average at the end (other processes share the cores): {result["load_average"]}')
    if args.simd:
        counts = result['rk4_lanes_vector_instructions'] = packed_instructions()
        print(
            'rk4_lanes vector instructions (4 or 8 doubles each): '
            + ', '.join(f'{n} {name}' for name, n in counts.items())
        )
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + '\n')


if __name__ == '__main__':
    main()
