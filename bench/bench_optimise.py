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

"""Benchmark of `valve-sim optimise`'s sequential search: the same Pareto set, fewer runs."""

# The summary above is also this script's --help description.
#
#     nice -n 19 .venv/bin/python bench/bench_optimise.py [--problems first,worked]
#         [--population P] [--generations G] [--samples N] [--confirm-samples M]
#         [--searches A,N,B] [--json FILE]
#
# Side by side in one run, on one local Dask cluster of `cores` workers (started and
# its kernels loaded first), for each problem of docs/optimise.md (the first example:
# d_c, k_p, V_c; the worked answer: six parameters), three searches:
#   A  full samples (--sequential off, today's search), seed 0
#   B  full samples, seed 1: how far two full-budget searches differ
#   N  the sequential search (the defaults), seed 0; its search stage includes the
#      resolution of the Pareto set's open candidates (their runs also said apart)
# each followed by its confirmation (reported apart). The Pareto designs that meet the
# yield on confirmation are compared on their nominal objectives, scaled to [0, 1]
# over the union of the three sets: hypervolume (reference point 1.1 in each
# objective) and each design's nearest match in A (with both confirmed yield
# intervals). N passes when it differs from A by no more than B does (hypervolume,
# largest nearest-match distance either way), and its search stage takes at most
# 10 % of A's runs and wall time (the workers' CPU seconds are reported too: on a
# shared machine the load decides the wall time). Without --population/--generations
# each problem runs at its docs/optimise.md budget (an hour or more per search on 2 cores).
# --earlier FILE takes the searches not run now from an earlier run's --json (same
# problem, sizes and seeds checked), so the two full-sample searches of a problem can run
# once and be compared with several versions of N; their load is reported beside (a
# problem's own load_start, load_end and keep, where files of several runs were merged).

import argparse
import json
import os
from pathlib import Path
import sys
import tempfile
import time

import numpy as np
from valve_sim.analysis.design.optimisation import (
    outcome_of,
    parse_design,
    parse_objectives,
    RobustProblem,
    search,
)
from valve_sim.analysis.design.report import runs_statement
from valve_sim.analysis.design.robust_yield import evaluate_candidate, evaluate_candidates
from valve_sim.analysis.design.sequential_yield import (
    FIRST_ROUND,
    rounds,
    STOP_ALPHA,
    verdict,
)
from valve_sim.analysis.studies.backend import DaskBackend
from valve_sim.analysis.studies.cases import preset_protocol
from valve_sim.analysis.studies.runner import run_cases
from valve_sim.core.parameters import load_parameters

LIMITS = 'r_d<=0.85,P_o_percent<=0.2'
REQUIRED_YIELD = 0.99
PROBLEMS = {
    'first': {'design': 'd_c=0.8e-3:1.2e-3,k_p=±20%,V_c=±20%',
              'tolerances': 'd_c=±7um,k_p=±10%,V_c=±5%', 'population': 24, 'generations': 20},
    'worked': {'design': 'm_m=±20%,m_p=±20%,V_p=±20%,V_c=±20%,d_c=±20%,k_p=±20%',
               'tolerances': 'd_c=±7um,k_p=±10%,m_m=±2%,m_p=±2%,V_p=±5%,V_c=±5%',
               'population': 32, 'generations': 40},
}
RUNS = (('A', 0, None), ('N', 0, 'default'), ('B', 1, None))  # label, seed, sequential


def problem_of(params, spec, samples, confirm_samples, seed, sequential):
    """Return the RobustProblem of a problem of docs/optimise.md."""
    preset, _ = preset_protocol('held-preset', params)
    extra = {} if sequential == 'default' else {'stop_alpha': sequential}
    return RobustProblem(
        params=params, design=tuple(parse_design([spec['design']], params)),
        objectives=tuple(parse_objectives(['P_1_percent,T_s_ms'], None)),
        limits=tuple(LIMITS.split(',')), tolerances=tuple(spec['tolerances'].split(',')),
        required_yield=REQUIRED_YIELD, preset_pressure=preset, samples=samples, seed=seed,
        confirm_samples=confirm_samples, **extra,
    ).check()


def one_search(problem, backend, folder, population, generations):
    """Return the measures of one search and its confirmation."""
    cpu, start = workers_cpu(backend), time.perf_counter()
    records = search(problem, backend, folder, population, generations)
    searched, cpu = time.perf_counter(), workers_cpu(backend) - cpu
    outcome = outcome_of(problem, records, backend, folder, False)
    confirmed = time.perf_counter()
    rows = [row for _, row in records]
    designs = [(row, confirm) for _, row, confirm in outcome['pareto']
               if confirm is not None and problem.feasible(confirm)]
    runs = runs_statement(records, outcome)  # as pareto.json states them
    resolution = runs['search']['resolution']
    return {
        'search_s': searched - start, 'confirm_s': confirmed - searched, 'search_cpu_s': cpu,
        'search_runs': runs['search']['runs'], 'full_runs': runs['search']['full_sample_runs'],
        'confirm_runs': runs['confirmation']['runs'],
        'decisions': runs['search']['decisions'], 'pareto_searched': len(outcome['pareto']),
        'resolved': resolution['candidates'], 'resolution_runs': resolution['runs'],
        'replayed': {first: replay(rows, problem.required_yield, first)
                     for first in (16, 32)} if problem.stop_alpha is None else None,
        'designs': [{'label': row['label'], 'design': row['design'],
                     'objectives': problem.scores(row)[0], 'ci95': confirm['ci95'],
                     'yield': confirm['yield']} for row, confirm in designs],
    }


def workers_cpu(backend):
    """Return the CPU seconds the cluster's worker processes have used so far."""
    return sum(backend.client.run(time.process_time).values())


def replay(rows, required_yield, first_round=FIRST_ROUND, alpha=STOP_ALPHA):
    """
    Replay the stopping rule on full-sample rows' pass strings (dominance, deferral left out).

    Return {decision: count}, the runs it would take against the full samples', and the
    candidates whose early verdict differs from their full sample's.
    """
    decisions, runs, full, differ = {}, 0, 0, 0
    for row in rows:
        verdicts, decision = row['pass'], 'nominal' if row['error'] else None
        nominal = row['nominal'] or {}
        if decision is None and not nominal.get('pass'):
            decision = 'nominal'
        counts = rounds(len(verdicts), first_round) if verdicts else [0]
        used = 0
        for number, count in enumerate(counts if decision is None else []):
            used = count
            decision = ('full' if number == len(counts) - 1 else
                        verdict(verdicts[:count].count('1'), count, len(verdicts),
                                required_yield, alpha, len(counts) - 1))
            if decision is not None:
                break
        decisions[decision] = decisions.get(decision, 0) + 1
        runs, full = runs + used + 1, full + len(verdicts) + 1
        meets = bool(verdicts) and verdicts.count('1') / len(verdicts) >= required_yield
        differ += (decision == 'below' and meets) or (decision == 'above' and not meets)
    return {'decisions': decisions, 'runs': runs, 'full_runs': full, 'differ': differ}


def compare(runs):
    """Add hypervolumes and nearest matches in A to runs {label: measures}."""
    from pymoo.indicators.hv import HV

    points = np.array([d['objectives'] for run in runs.values() for d in run['designs']])
    if not len(points):
        for run in runs.values():
            run.update(hypervolume=0.0, nearest_in_A=[], furthest_from=0.0)
        return
    low, span = points.min(axis=0), np.ptp(points, axis=0)
    span = np.where(span > 0, span, 1.0)
    scaled = {k: np.array([(np.array(d['objectives']) - low) / span for d in run['designs']])
              for k, run in runs.items()}
    indicator = HV(ref_point=np.full(points.shape[1], 1.1))
    for label, run in runs.items():
        run['hypervolume'] = float(indicator(scaled[label])) if len(scaled[label]) else 0.0
        run['nearest_in_A'] = [float(np.min(np.linalg.norm(scaled['A'] - p, axis=1)))
                               for p in scaled[label]] if len(scaled['A']) else []
        if not (len(scaled[label]) and len(scaled['A'])):  # one set empty: no match
            run['furthest_from'] = 0.0 if len(scaled[label]) == len(scaled['A']) else np.inf
            continue
        run['furthest_from'] = max(run['nearest_in_A'] + [
            float(np.min(np.linalg.norm(scaled[label] - p, axis=1))) for p in scaled['A']])


def checks_of(runs):
    """
    Return the checks of N against A and B: same Pareto set, at most 10 % of the search.

    hypervolume and nearest_matches: N differs from A by no more than B does, either
    way; not_worse: N's hypervolume falls short of A's by no more than B's differs.
    """
    a, b, n = runs['A'], runs.get('B'), runs['N']
    spread = None if b is None else abs(b['hypervolume'] - a['hypervolume'])
    return {
        'hypervolume': None if b is None else abs(n['hypervolume'] - a['hypervolume'])
        <= spread,
        'not_worse': None if b is None else n['hypervolume'] >= a['hypervolume'] - spread,
        'nearest_matches': None if b is None else n['furthest_from'] <= b['furthest_from'],
        'runs_10_percent': n['search_runs'] <= 0.10 * a['search_runs'],
        'wall_10_percent': n['search_s'] <= 0.10 * full_seconds(runs),
    }


def full_seconds(runs):
    """Return the full-sample search's wall time: the mean of A's and B's (the load drifts)."""
    return float(np.mean([runs[label]['search_s'] for label in ('A', 'B') if label in runs]))


def report(name, runs, checks):
    """Print one problem's three searches side by side."""
    print(f'\n== {name} ==')
    for label, run in runs.items():
        share = 100 * run['search_runs'] / run['full_runs']
        print(f"{label}: search {run['search_runs']:,} runs ({share:.1f} % of full "
              f"samples), {run['search_s']:.0f} s ({run['search_cpu_s']:.0f} s of the "
              f"workers' CPU; {run.get('resolution_runs', 0):,} runs of it resolving "
              f"{run.get('resolved', 0)} open candidates); confirmation "
              f"{run['confirm_runs']:,} runs, "
              f"{run['confirm_s']:.0f} s; decisions {run['decisions']}; "
              f"{len(run['designs'])} of {run['pareto_searched']} Pareto designs meet the yield "
              f"on confirmation; hypervolume {run.get('hypervolume', 0):.4f}; furthest nearest "
              f"match to A {run.get('furthest_from', 0):.4f}")
        distances = run['nearest_in_A'] or [np.nan] * len(run['designs'])
        for design, distance in zip(run['designs'], distances):
            low, high = design['ci95']
            p_1, t_s = design['objectives']
            print(f"   {design['label']:<15} P_1 {p_1:.4f} %  T_s {t_s:.2f} ms  yield "
                  f'{100 * design["yield"]:.1f} % ({100 * low:.1f}-{100 * high:.1f})  '
                  f'nearest in A at {distance:.4f}')
    for label in [label for label in ('A', 'B') if label in runs]:
        for first, replayed in runs[label]['replayed'].items():
            print(f"the rule replayed on {label}'s full samples, first round {first}: "
                  f"{replayed['decisions']}, {replayed['runs']:,} of {replayed['full_runs']:,} "
                  f"runs; {replayed['differ']} early verdicts differ from the full sample's")
    if not checks:
        return
    a, n = runs['A'], runs['N']
    print(f"N against A: {100 * n['search_runs'] / a['search_runs']:.1f} % of the runs, "
          f"{100 * n['search_s'] / full_seconds(runs):.1f} % of the mean wall time of "
          f"{' and '.join(label for label in ('A', 'B') if label in runs)}'s searches, "
          f"{100 * n['search_cpu_s'] / a['search_cpu_s']:.1f} % of A's workers' CPU; "
          f'checks {checks}')


def taken_over(earlier, name, label, population, generations, args):
    """Return search label of problem name from an earlier run's JSON, its sizes checked."""
    settings, problem = earlier['settings'], earlier[name]
    asked = (population, generations, args.samples, args.confirm_samples)
    found = (problem['population'], problem['generations'], settings['samples'],
             settings['confirm_samples'])
    if asked != found:
        sys.exit(f'--earlier: {name} {label} ran at {found} (population, generations, '
                 f'samples, confirm samples), not {asked}')
    run = dict(problem['runs'][label])
    load = {key: problem.get(key, earlier[key]) for key in ('load_start', 'load_end')}
    run['earlier'] = {'file': args.earlier, **load}
    kept = Path(problem.get('keep', settings['keep']) or '/nonexistent') / name / label
    rows = [json.loads(line) for path in sorted(kept.glob('generation_*.jsonl'))
            for line in path.read_text().splitlines()[1:]]
    if rows and run['replayed'] is not None:  # the rule of this version, on its kept rows
        run['replayed'] = {first: replay(rows, REQUIRED_YIELD, first) for first in (16, 32)}
    print(f"{name} {label}: taken from {args.earlier} (load {load['load_start']:.1f} "
          f"at its start, {load['load_end']:.1f} at its end)", file=sys.stderr)
    return run


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--problems', default='first,worked')
    parser.add_argument('--population', type=int, help="default: each problem's own")
    parser.add_argument('--generations', type=int, help="default: each problem's own")
    parser.add_argument('--samples', type=int, default=256)
    parser.add_argument('--confirm-samples', type=int, default=1024)
    parser.add_argument('--searches', default='A,N,B',
                        help='which searches, in this order (without A and N no check, '
                        'without B no same-Pareto-set check)')
    parser.add_argument('--json', metavar='FILE')
    parser.add_argument('--earlier', metavar='FILE',
                        help="an earlier run's --json: the searches not run now are taken "
                        'from it')
    parser.add_argument('--keep', metavar='DIR', help="keep every search's results files here")
    args = parser.parse_args()
    params = load_parameters().params
    cores = os.cpu_count() or 1
    result = {'cores': cores, 'load_start': os.getloadavg()[0], 'settings': vars(args)}
    earlier = json.loads(Path(args.earlier).read_text()) if args.earlier else {}
    backend = DaskBackend(workers=cores).start()
    try:
        with tempfile.TemporaryDirectory() as scratch:
            folder = args.keep or scratch
            warm = problem_of(params, PROBLEMS['first'], 16, 0, 0, None)
            evaluate_candidate(warm.case(0, 'warm', {}))
            run_cases([warm.case(i, f'warm {i}', {}) for i in range(cores)],
                      Path(folder) / 'warm.jsonl', backend, batch_size=1,
                      evaluate=evaluate_candidates,
                      progress_stream=None)
            for name in args.problems.split(','):
                spec = PROBLEMS[name]
                population = args.population or spec['population']
                generations = args.generations or spec['generations']
                runs = {}
                chosen = args.searches.split(',')
                searches = sorted((run for run in RUNS if run[0] in chosen),
                                  key=lambda run: chosen.index(run[0]))
                for label, seed, sequential in searches:
                    problem = problem_of(params, spec, args.samples, args.confirm_samples,
                                         seed, sequential)
                    if label in earlier.get(name, {}).get('runs', {}):
                        runs[label] = taken_over(earlier, name, label, population,
                                                 generations, args)
                        continue
                    print(f'{name} {label}: {generations} x {population} x {args.samples}',
                          file=sys.stderr, flush=True)
                    runs[label] = one_search(problem, backend, Path(folder) / name / label,
                                             population, generations)
                compare(runs)
                checks = checks_of(runs) if 'A' in runs and 'N' in runs else {}
                report(name, runs, checks)
                result[name] = {'population': population, 'generations': generations,
                                'runs': runs, 'checks': checks}
                result['load_end'] = os.getloadavg()[0]
                if args.json:  # after each problem: a later one's failure loses nothing
                    Path(args.json).write_text(json.dumps(result, indent=2) + '\n')
    finally:
        backend.close()
    print(f"load average {result['load_start']:.1f} at the start, {result['load_end']:.1f} at "
          'the end')


if __name__ == '__main__':
    main()
