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

"""Benchmark of `valve-sim optimise`: one candidate's yield, and scaling over Dask workers."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_optimise_scaling.py [--samples 1000] [--generations 2]
#         [--json FILE]
#
# Measured side by side in one run (the machine is shared: compare the ratios):
# 1. single: simulate() (the whole 1.25 s with rk4_steps) + step_measures, run after
#    run on one core, 32 valves of the candidate's tolerance batch: the single-run
#    rate; x cores is the reference.
# 2. candidate: one candidate's --samples-valve yield (Latin hypercube: any count),
#    as the optimiser's work unit (analysis.design.robust_yield.evaluate_candidate: preset,
#    one batch of the lanes kernel, measures, decay rates) in this process, one core.
# 3. generation: `cores` such candidates on a local Dask cluster of `cores` workers
#    (started beforehand), as one generation of the optimiser runs them.
# 4. scaling: the worked answer of docs/optimise.md at a reduced budget
#    (--generations, no confirmation) end to end with --workers 1 and 2; the
#    projection beyond assumes what the two runs show, a generation of P candidates
#    on W workers takes ceil(P / W) candidate times.

import argparse
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

from valve_sim.analysis.design.optimisation import parse_design, parse_objectives, RobustProblem
from valve_sim.analysis.design.robust_yield import evaluate_candidate, evaluate_candidates
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP as SCENARIO
from valve_sim.analysis.steps.measures import step_measures
from valve_sim.analysis.studies.backend import DaskBackend
from valve_sim.analysis.studies.cases import preset_protocol
from valve_sim.analysis.studies.runner import run_cases
from valve_sim.analysis.studies.tolerances import draw, parse_variations
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import simulate
from valve_sim.core.steady_state import with_preset_pressure


DESIGN = 'm_m=±20%,m_p=±20%,V_p=±20%,V_c=±20%,d_c=±20%,k_p=±20%'
TOLERANCES = 'd_c=±7um,k_p=±10%,m_m=±2%,m_p=±2%,V_p=±5%,V_c=±5%'
OBJECTIVES, LIMITS = 'P_1_percent,T_s_ms', 'r_d<=0.85,P_o_percent<=0.2'
POPULATION = 24


def worked_command(out, workers, generations, samples):
    """Return the worked answer's command (docs/optimise.md) at a budget, no confirmation."""
    return [sys.executable, '-m', 'valve_sim.commands.cli', 'optimise', '--design', DESIGN,
            '--minimise', OBJECTIVES, '--limits', LIMITS, '--tolerance', TOLERANCES,
            '--yield', '0.99', '--samples', str(samples), '--confirm-samples', '0',
            '--population', str(POPULATION), '--generations', str(generations),
            '--workers', str(workers), '--out', str(out)]


def timed(function):
    """Return (wall seconds, CPU seconds of this process, result) of function()."""
    wall, cpu = time.perf_counter(), time.process_time()
    result = function()
    return time.perf_counter() - wall, time.process_time() - cpu, result


def candidate_problem(params, samples):
    """Return the worked answer's problem with samples valves per candidate."""
    preset, _ = preset_protocol('held-preset', params)
    return RobustProblem(
        params=params, design=tuple(parse_design([DESIGN], params)),
        objectives=tuple(parse_objectives([OBJECTIVES], None)), limits=tuple(LIMITS.split(',')),
        tolerances=tuple(TOLERANCES.split(',')), required_yield=0.99, preset_pressure=preset,
        samples=samples, sampler='lhs', confirm_samples=0,
    )


def single_runs(params, count):
    """simulate() + step_measures of count valves of the tolerance batch, one after another."""
    distributions = parse_variations([TOLERANCES], params)
    values = draw(distributions, count, 5, 'random')
    valves = [with_preset_pressure({**params, **{d.name: float(v) for d, v in zip(
        distributions, row)}}, 7e6) for row in values]
    return [step_measures(w.time, w['supply_pressure'], w['main_valve_displacement'],
                          SCENARIO.step_time) for w in (simulate(v, SCENARIO) for v in valves)]


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--samples', type=int, default=1000)
    parser.add_argument('--generations', type=int, default=2,
                        help='generations of the scaling runs (default 2)')
    parser.add_argument('--scaling-samples', type=int, default=128,
                        help='valves per candidate in the scaling runs (default 128)')
    parser.add_argument('--json', metavar='FILE')
    args = parser.parse_args()
    cores = os.cpu_count() or 1
    params = load_parameters().params
    problem = candidate_problem(params, args.samples)
    case = problem.case(0, 'bench', {})
    single_runs(params, 2)
    evaluate_candidate({**case, 'samples': 16})  # kernels loaded
    result = {'cores': cores, 'samples': args.samples, 'load_start': os.getloadavg()[0]}
    wall, cpu, _ = timed(lambda: single_runs(params, 32))
    result['single_run_s'] = {'wall': wall / 32, 'cpu': cpu / 32}
    wall, cpu, row = timed(lambda: evaluate_candidate(case))
    result['candidate_s'] = {'wall': wall, 'cpu': cpu, 'yield': row['yield']}
    runs = args.samples + 1
    single_rate = cores / result['single_run_s']['wall']
    result['candidate_rate_runs_per_s'] = runs / wall
    result['candidate_vs_single_x_cores'] = runs / wall / single_rate
    backend = DaskBackend(workers=cores).start()
    try:
        cases = [problem.case(i, f'bench {i}', {}) for i in range(cores)]
        with tempfile.TemporaryDirectory() as folder:
            warm = [{**case, 'samples': 16} for case in cases]  # each worker loads the kernels
            run_cases(warm, Path(folder) / 'w.jsonl', backend, batch_size=1,
                      evaluate=evaluate_candidates, progress_stream=None)
            wall, _, _ = timed(lambda: run_cases(cases, Path(folder) / 'r.jsonl', backend,
                                                 batch_size=1, evaluate=evaluate_candidates,
                                                 progress_stream=None))
    finally:
        backend.close()
    result['generation_s'] = wall
    result['generation_rate_runs_per_s'] = cores * runs / wall
    result['generation_vs_single_x_cores'] = cores * runs / wall / single_rate
    scaling = {}
    for workers in (1, 2):
        with tempfile.TemporaryDirectory() as folder:
            command = worked_command(Path(folder) / 'out', workers, args.generations,
                                     args.scaling_samples)
            start = time.perf_counter()
            done = subprocess.run(command, capture_output=True, text=True)
            scaling[workers] = time.perf_counter() - start
            if done.returncode:
                sys.exit(done.stderr)
    # T(W) = start + generations * ceil(P / W) * candidate, fitted to the two runs
    candidate = 2.0 * (scaling[1] - scaling[2]) / (args.generations * POPULATION)
    start = max(0.0, scaling[1] - args.generations * POPULATION * candidate)
    result['scaling_s'] = scaling
    result['scaling_speedup_2'] = scaling[1] / scaling[2]
    result['fitted_start_s'], result['fitted_candidate_s'] = start, candidate
    result['projection_s'] = {
        workers: start + args.generations * math.ceil(POPULATION / workers) * candidate
        for workers in (4, 8, 12, 24, 48)
    }
    result['load_end'] = os.getloadavg()[0]
    single = result['single_run_s']['wall']
    print(f'single run (simulate + measures, one core): {single * 1e3:.1f} ms wall; '
          f'single-run rate x {cores} cores = {single_rate:.0f} runs/s')
    print(f'one candidate, {args.samples} valves + nominal, one core: '
          f"{result['candidate_s']['wall']:.1f} s ({result['candidate_rate_runs_per_s']:.0f} "
          f"runs/s) = {result['candidate_vs_single_x_cores']:.2f} x the single-run rate x cores")
    print(f'{cores} candidates on {cores} Dask workers: {wall:.1f} s '
          f"({result['generation_rate_runs_per_s']:.0f} runs/s) = "
          f"{result['generation_vs_single_x_cores']:.2f} x the single-run rate x cores")
    projected = ', '.join(f'{w} workers {t:.0f} s' for w, t in result['projection_s'].items())
    print(f'worked answer, {args.generations} generations of {POPULATION} x '
          f'{args.scaling_samples} valves: 1 worker {scaling[1]:.0f} s, 2 workers '
          f"{scaling[2]:.0f} s (speed-up {result['scaling_speedup_2']:.2f}); "
          + (f'fitted start {start:.0f} s + {candidate:.2f} s a candidate; projected {projected}'
             if candidate > 0 else 'no gain from the second worker: no projection (busy cores?)'))
    print(f"load average {result['load_start']:.1f} at the start, {result['load_end']:.1f} at "
          'the end')
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + '\n')


if __name__ == '__main__':
    main()
