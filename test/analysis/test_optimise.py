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
`valve-sim optimise`: a known robust optimum, the yield against `tolerance`, resume, errors.

Small budgets throughout: a few candidates of a few sampled valves each.
"""

import csv
import io
import json
import re
import subprocess
import sys

import numpy as np
import pytest
from valve_sim.analysis.design import robust_yield
from valve_sim.analysis.design.optimisation import (
    outcome_of,
    pareto_front,
    pareto_set,
    parse_design,
    parse_objectives,
    resolve,
    RobustProblem,
    search,
)
from valve_sim.analysis.design.report import parameter_file_text
from valve_sim.analysis.design.robust_yield import evaluate_candidate, evaluate_candidates
from valve_sim.analysis.design.sequential_yield import (
    longest_first,
    look,
    rounds,
    runs_of,
    STOP_ALPHA,
    suspects,
    verdict,
)
from valve_sim.analysis.studies.backend import DaskBackend, SerialBackend
from valve_sim.analysis.studies.cases import preset_protocol
from valve_sim.analysis.studies.tolerances import parse_variations, unit_samples
from valve_sim.commands.cli import main
from valve_sim.core.parameters import load_parameters


D_C = 'damping_orifice_diameter'


def problem_of(reference, design, minimise, limits, tolerances, **settings):
    """Return a RobustProblem on the reference valve, preset held at its cracking pressure."""
    preset, _ = preset_protocol('held-preset', reference)
    return RobustProblem(
        params=reference,
        design=tuple(parse_design(design, reference)),
        objectives=tuple(parse_objectives(minimise, None)),
        limits=tuple(limits),
        tolerances=tuple(tolerances),
        preset_pressure=preset,
        **{'required_yield': 1.0, 'min_decay_rate': None, 'confirm_samples': 0, **settings},
    ).check()


def test_the_optimiser_finds_a_known_robust_optimum(reference, tmp_path):
    # P_1 falls and r_d rises monotonically with d_c below the reference d_c (docs/model.md,
    # the parameter study; above it r_d flattens out). Minimise P_1 with r_d <= r_d(d_lim),
    # d_lim 3 % below the reference d_c, for every valve made within d_c ±1 %: the optimum
    # is the d_c whose largest sampled valve sits at d_lim. With 8 Sobol points u that
    # valve is d (0.99 + 0.02 max u), so d* = d_lim / (0.99 + 0.02 max u), about 0.8 %
    # below the nominal-only answer d_lim.
    nominal = reference[D_C]
    limit_at = 0.97 * nominal
    design = [f'd_c={0.90 * nominal!r}:{1.03 * nominal!r}']
    probe = problem_of(reference, design, ['P_1_percent'], ['r_d<=1'], ['d_c=±1%'], samples=8)
    r_d = evaluate_candidate(probe.case(0, 'probe', {D_C: limit_at}))['nominal']['measures']['r_d']
    problem = problem_of(reference, design, ['P_1_percent'], [f'r_d<={r_d!r}'],
                         ['d_c=±1%'], samples=8)
    optimum = limit_at / (0.99 + 0.02 * unit_samples(8, 1, 0, 'sobol').max())
    records = search(problem, SerialBackend(), tmp_path, population=8, generations=8,
                     stream=None)
    values = [(row['design'][D_C], problem.feasible(row)) for _, row in records
              if not problem.undecided(row)]
    assert all(feasible == (d <= optimum) for d, feasible in values), 'the yield decides'
    assert any(d > optimum for d, _ in values), 'the search must try beyond the optimum'
    (best,) = outcome_of(problem, records, SerialBackend(), tmp_path, False)['pareto']
    found = best[1]['design'][D_C]
    assert optimum - 0.25 * (limit_at - optimum) < found <= optimum
    assert best[1]['yield'] == 1.0 and best[1]['pass'] == '1' * 8
    # left undecided: only designs of a higher P_1 (a smaller d_c) than the one found
    assert all(row['design'][D_C] < found for _, row in records if problem.undecided(row))


def test_the_confirmed_yields_of_two_pareto_designs_match_tolerance(reference, tmp_path):
    # A sequential search (rounds of 4, 8, 16 valves), then the confirmation's 16 fresh
    # valves of two Pareto designs against `valve-sim tolerance` on each design's
    # parameter file, the same tolerances, sampler, seed (the next one) and limit:
    # every valve judged the same, so the confirmed yield means what it meant.
    tolerances, limit = 'd_c=±7um,k_p=±10%', 'r_d<=0.855'
    problem = problem_of(reference, ['d_c=±10%', 'k_p=±20%'], ['P_1_percent', 'T_s_ms'],
                         [limit], [tolerances], samples=8, first_round=4, confirm_samples=16,
                         required_yield=0.5, seed=3)
    records = search(problem, SerialBackend(), tmp_path, population=6, generations=2,
                     stream=None)
    outcome = outcome_of(problem, records, SerialBackend(), tmp_path, False)
    pareto = [(row, confirmed) for _, row, confirmed in outcome['pareto']]
    assert len(pareto) >= 2, 'two Pareto designs make the test'
    verdicts = set()
    cluster = DaskBackend(workers=1).start()  # one cluster for both: its worker loads once
    try:
        for number, (row, confirmed) in enumerate(pareto[:2]):
            assert confirmed['samples'] == 16 and confirmed['decision'] == 'full'
            params_file = tmp_path / f'design{number}.yaml'
            params_file.write_text(parameter_file_text(problem, row['design'], 'test design'))
            out = tmp_path / f'tolerance{number}'
            assert main(['tolerance', '--params', str(params_file), '--vary', tolerances,
                         '--samples', '16', '--sampler', 'sobol', '--seed', '4', '--limits',
                         limit, '--scheduler', cluster.cluster.scheduler_address,
                         '--out', str(out)]) == 0
            with open(out / 'samples.csv') as stream:
                judged = ''.join(line['pass'] for line in csv.DictReader(stream))
            assert judged == confirmed['pass']
            verdicts |= set(judged)
    finally:
        cluster.close()
    assert verdicts == {'0', '1'}, 'passing and failing valves make the test'


def sequential_candidate(reference, limits, required_yield, front=(), **settings):
    """Return (problem, row) of one candidate (d_c 1.02 mm): 16 Sobol valves in rounds of 4."""
    problem = problem_of(reference, ['d_c=±20%'], ['P_1_percent'], limits,
                         ['d_c=±2%,k_p=±5%'], samples=16, seed=3, first_round=4,
                         required_yield=required_yield, **settings)
    return problem, evaluate_candidate(problem.case(0, 'c', {D_C: 1.02e-3}, front=front))


def test_the_stopping_rule_and_the_common_draws(reference):
    problem, every = sequential_candidate(reference, ['P_1_percent<=99'], 0.3, stop_alpha=None)
    assert (every['decision'], every['samples'], every['runs']) == ('full', 16, 17)
    nominal = every['nominal']['measures']['P_1_percent']
    half = [f'P_1_percent<={nominal!r}']  # about half the valves overshoot more
    _, mixed = sequential_candidate(reference, half, 0.3, stop_alpha=None)
    assert 0 < mixed['passed'] < 16
    # far above the target: decided after the first round
    problem, above = sequential_candidate(reference, ['P_1_percent<=99'], 0.3)
    assert (above['decision'], above['samples'], above['pass']) == ('above', 4, '1111')
    assert problem.feasible(above)
    # far below: stopped early, its valves the first ones of the full sample
    problem, below = sequential_candidate(reference, half, 0.99)
    assert below['decision'] == 'below' and below['samples'] < 16
    assert below['pass'] == mixed['pass'][:below['samples']] and not problem.feasible(below)
    # at the target: undecided at every look, the full sample, the same valves as one round
    problem, at = sequential_candidate(reference, half, mixed['yield'])
    assert (at['decision'], at['pass'], at['yield']) == ('full', mixed['pass'], mixed['yield'])
    assert problem.feasible(at)
    # a nominal valve out of spec takes no samples
    problem, out = sequential_candidate(reference, [f'P_1_percent<={nominal - 0.1!r}'], 0.3)
    assert (out['decision'], out['samples'], out['runs']) == ('nominal', 0, 1)
    assert not problem.feasible(out)
    # dominated by a promising design: no samples, undecided, not counted as feasible,
    # ranked as meeting the yield (behind the design that dominates it)
    problem, behind = sequential_candidate(reference, ['P_1_percent<=99'], 0.99,
                                           front=[[nominal - 0.01]])
    assert (behind['decision'], behind['samples'], behind['runs']) == ('dominated', 0, 1)
    assert problem.undecided(behind) and not problem.feasible(behind)
    assert problem.scores(behind)[1] == [0.0, 0.0]
    # still undecided after defer_after valves: left open, its estimate so far for the
    # optimiser; resolved, it runs on to the same verdict and valves as without deferral
    problem, left = sequential_candidate(reference, half, mixed['yield'], defer_after=5)
    assert (left['decision'], left['pass']) == ('open', mixed['pass'][:8])
    assert problem.undecided(left) and not problem.feasible(left)
    resolved = evaluate_candidate(problem.case(0, 'c', {D_C: 1.02e-3}, resolving=True))
    assert (resolved['decision'], resolved['pass']) == ('full', mixed['pass'])


def test_suspected_valves_first_decide_a_failing_candidate_exactly(reference):
    # The valves that failed elsewhere run first when resolving: a candidate they
    # already fail is 'below' on them alone, as its full sample says; one they do not
    # fail goes on as without them, its rows the same, their runs spent.
    nominal = sequential_candidate(reference, ['P_1_percent<=99'], 0.3)[1]['nominal']
    half = [f"P_1_percent<={nominal['measures']['P_1_percent']!r}"]
    _, every = sequential_candidate(reference, half, 0.3, stop_alpha=None)
    failing = [i for i, verdict in enumerate(every['pass']) if verdict == '0']
    passing = [i for i, verdict in enumerate(every['pass']) if verdict == '1']
    assert suspects([every, {'valves': [failing[-1], 3], 'pass': '01'}]) == failing
    assert suspects([every], count=2) == failing[:2]
    required = (every['passed'] + 1) / 16  # just above what the full sample gives
    problem = problem_of(reference, ['d_c=±20%'], ['P_1_percent'], half, ['d_c=±2%,k_p=±5%'],
                         samples=16, seed=3, first_round=4, required_yield=required)
    case = problem.case(0, 'c', {D_C: 1.02e-3}, resolving=True)
    plain = evaluate_candidate(case)
    assert not problem.feasible(plain)
    found = evaluate_candidate({**case, 'suspects': failing})
    assert (found['decision'], found['valves'], found['pass']) == (
        'below', failing, '0' * len(failing))
    assert found['runs'] == len(failing) + 1 and not problem.feasible(found)
    spent = evaluate_candidate({**case, 'suspects': passing[:3]})
    assert {**spent, 'runs': spent['runs'] - 3} == plain


def test_curtailment_is_the_full_samples_verdict_early():
    # 3 failures in 128 rule out 254 passes of 256 (99 %): below, though the interval at
    # that look still reaches above 99 %; 2 failures leave it open, as does 1 of 4 at 75 %
    assert look(125, 128, 0.99, STOP_ALPHA, 4) is None
    assert verdict(125, 128, 256, 0.99, STOP_ALPHA, 4) == 'below'
    assert verdict(126, 128, 256, 0.99, STOP_ALPHA, 4) is None
    assert verdict(3, 4, 16, 0.75, STOP_ALPHA, 2) is None
    assert verdict(3, 8, 16, 0.75, STOP_ALPHA, 2) == 'below'


def test_the_pareto_set_is_resolved_as_deciding_every_candidate_would(reference, tmp_path):
    # Five candidates (P_1, T_s; the search's decision -> what resolving it decides):
    # 0 (1, 1) open -> misses; 1 (2, 2) dominated -> meets; 2 (3, 0.5) open -> meets;
    # 3 (4, 4) meets, decided; 4 (0.5, 3) below. The front of the feasible and undecided
    # ones is {0, 2}, then {1, 2}: 0, 2 and then 1 are resolved, 3 and 4 never are; the
    # Pareto set {1, 2} is the one deciding every candidate gives.
    problem = problem_of(reference, ['d_c=±10%'], ['P_1_percent', 'T_s_ms'], ['r_d<=2'],
                         ['d_c=±7um'], samples=4, required_yield=0.9)
    template = evaluate_candidate(problem.case(0, 'template', {}))
    table = {0: ((1, 1), 'open', 0.5), 1: ((2, 2), 'dominated', 1.0),
             2: ((3, 0.5), 'open', 1.0), 3: ((4, 4), 'full', 1.0), 4: ((0.5, 3), 'below', 0.0)}

    def row(index, decision, passed, samples=4):
        (p_1, t_s), _, _ = table[index]
        nominal = {**template['nominal'], 'measures': {
            **template['nominal']['measures'], 'P_1_percent': p_1, 'T_s_ms': t_s}}
        return {**template, 'index': index, 'label': f'c{index}', 'nominal': nominal,
                'decision': decision, 'samples': samples, 'runs': samples + 1,
                'passed': passed, 'yield': passed / samples if samples else 0.0,
                'pass': '1' * passed + '0' * (samples - passed)}

    resolved = []

    def resolving(cases):
        assert all(c['defer_after'] is None and c['front'] == [] for c in cases)
        resolved.extend(case['index'] for case in cases)
        return [row(case['index'], 'full', round(4 * table[case['index']][2])) for case in cases]

    searched = [(1, row(i, decision, {'open': 4, 'dominated': 0}.get(decision, round(4 * y)),
                        0 if decision == 'dominated' else 4))
                for i, (_, decision, y) in table.items()]
    records = resolve(problem, searched, SerialBackend(), tmp_path, evaluate=resolving,
                      stream=None)
    assert resolved == [0, 2, 1]
    assert [row['label'] for _, row in pareto_set(problem, records)] == ['c1', 'c2']
    every = [(1, row(i, 'full', round(4 * y))) for i, (_, _, y) in table.items()]
    assert pareto_set(problem, records) == [
        (g, {**r, 'runs': r['runs'] + searched[r['index']][1]['runs'], 'resolution_runs':
             r['runs'], 'search_decision': searched[r['index']][1]['decision']})
        for g, r in pareto_set(problem, every)]
    assert len(list(tmp_path.glob('resolve_*.jsonl'))) == 2
    resolved.clear()
    assert resolve(problem, searched, SerialBackend(), tmp_path, True, resolving, None) == records
    assert resolved == [], 'resumed: read from its files'


class Recording(SerialBackend):
    """A serial backend of two workers that records its batches."""

    workers = 2

    def __init__(self):
        self.batches = []

    def run(self, evaluate, batches):
        self.batches += batches
        return super().run(evaluate, batches)


def test_split_rounds_and_the_nominal_stage_change_no_row(reference, monkeypatch):
    # The nominal stage runs a generation's nominal valves as one batch per worker, the
    # candidates go out longest first; on a Dask worker a round of more than SPLIT_VALVES
    # valves goes out as tasks of that many (2 here: an in-process cluster, so that the
    # patch reaches its worker). None of them changes a row.
    from distributed import Client, get_task_stream, LocalCluster

    problem = problem_of(reference, ['d_c=±20%'], ['P_1_percent'], ['P_1_percent<=99'],
                         ['d_c=±2%,k_p=±5%'], samples=8, stop_alpha=None)
    cases = [problem.case(i, f'c{i}', {D_C: d}) for i, d in enumerate((0.98e-3, 1.02e-3, -1.0))]
    alone = evaluate_candidates(cases)
    assert alone[2]['error'] and not alone[0]['error'] and alone[0]['samples'] == 8
    two = Recording()
    staged = robust_yield.nominal_stage(evaluate_candidates, cases, two)
    assert [[case['index'] for case in batch] for batch in two.batches] == [[0, 1, 2]]
    from valve_sim.core.batch import LANES

    assert robust_yield.NOMINAL_GROUP == LANES
    monkeypatch.setattr(robust_yield, 'NOMINAL_GROUP', 2)  # 3 valves: two batches of 2 and 1
    two.batches = []
    staged = robust_yield.nominal_stage(evaluate_candidates, cases, two)
    assert [[case['index'] for case in batch] for batch in two.batches] == [[0, 1], [2]]
    assert sorted(staged.keywords['nominals']) == [0, 1]  # no nominal valve for the third
    assert json.dumps(staged(cases)) == json.dumps(alone)
    # longest first: a nominal valve further inside its limit (here: a lower P_1), then
    # the nearer one, the one without samples last; only the order changes
    two.batches = []
    assert list(longest_first(two, staged).run(len, [[case] for case in cases])) == [1, 1, 1]
    lower_p_1 = min((0, 1), key=lambda i: alone[i]['nominal']['measures']['P_1_percent'])
    assert [batch[0]['index'] for batch in two.batches] == [lower_p_1, 1 - lower_p_1, 2]
    assert longest_first(two, evaluate_candidates) is two
    monkeypatch.setattr(robust_yield, 'SPLIT_VALVES', 2)
    with LocalCluster(processes=False, n_workers=1, threads_per_worker=1,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        with get_task_stream(client) as tasks:
            split = client.submit(evaluate_candidates, cases, pure=False).result()
    assert json.dumps(split) == json.dumps(alone)
    chunks = [task for task in tasks.data if task['key'].startswith('_judged_runs')]
    assert len(chunks) == 8, 'the 8 valves of each of two candidates in tasks of 2'


@pytest.mark.parametrize('required, true_yield, wrong', [
    (0.99, 0.99, 'below'), (0.99, 0.995, 'below'), (0.9, 0.8999, 'above')])
def test_a_wrong_early_stop_is_at_most_half_alpha(required, true_yield, wrong):
    # The stated error rates: valves passing independently with the true yield, the
    # rule's looks at 16, 32, 64 and 128 of 256 valves stop on the wrong side of the target
    # in at most alpha / 2 of 20,000 candidates (plus the Monte Carlo's 4 sigma).
    counts = rounds(256)
    decided = {n: [look(k, n, required, STOP_ALPHA, len(counts) - 1) for k in range(n + 1)]
               for n in counts[:-1]}
    passes = np.random.default_rng(0).random((20_000, 256)) < true_yield
    stopped = np.zeros(len(passes), dtype=bool)
    wrong_stops = 0
    for n in counts[:-1]:
        verdict = np.array(decided[n], dtype=object)[passes[:, :n].sum(axis=1)]
        wrong_stops += int(np.sum((verdict == wrong) & ~stopped))
        stopped |= verdict != None  # noqa: E711 (elementwise)
    rate, limit = wrong_stops / len(passes), STOP_ALPHA / 2
    assert rate <= limit + 4 * (limit * (1 - limit) / len(passes)) ** 0.5
    assert rounds(16, 4) == [4, 8, 16] and rounds(8) == [8] and rounds(100) == [16, 32, 64, 100]


def test_the_budget_stops_the_search(reference, tmp_path):
    problem = problem_of(reference, ['d_c=±10%'], ['P_1_percent'], ['r_d<=0.87'],
                         ['d_c=±7um'], samples=4, required_yield=0.5)
    stream = io.StringIO()
    records = search(problem, SerialBackend(), tmp_path, population=4, generations=6,
                     stream=stream, budget=45)
    spent = {}
    for generation, row in records:
        spent[generation] = spent.get(generation, 0) + runs_of(row)
    total, last = sum(spent.values()), spent[max(spent)]
    assert 1 < max(spent) < 6 and total + last > 45
    assert all(sum(spent[g] for g in range(1, k + 1)) + spent[k] <= 45 for k in spent
               if k < max(spent)), 'each generation started within the budget'
    assert f'optimise: budget of 45 runs: {total} spent' in stream.getvalue()


class InterruptedBackend(SerialBackend):
    """Serial batches, with Ctrl-C after `batches` of them over all its calls."""

    def __init__(self, batches):
        self.left = batches

    def run(self, evaluate, batches):
        for rows in super().run(evaluate, batches):
            if self.left == 0:
                raise KeyboardInterrupt
            self.left -= 1
            yield rows


def test_resume_redoes_nothing_already_done(reference, tmp_path):
    problem = problem_of(reference, ['d_c=±10%', 'k_p=±10%'], ['P_1_percent', 'T_s_ms'],
                         ['r_d<=0.87'], ['d_c=±7um,k_p=±10%'], samples=4, confirm_samples=4,
                         required_yield=0.5)
    evaluated = []

    def counting(cases):
        evaluated.extend((case['label'], case['keep_samples']) for case in cases)
        return evaluate_candidates(cases)

    def optimise(folder, backend, resume):
        records = search(problem, backend, folder, 4, 3, resume, counting, stream=None)
        return records, outcome_of(problem, records, backend, folder, resume, counting, None)

    fresh = optimise(tmp_path / 'fresh', SerialBackend(), False)
    assert len(evaluated) == 12 + len(fresh[1]['pareto']) + 2
    evaluated.clear()
    with pytest.raises(KeyboardInterrupt):
        optimise(tmp_path / 'run', InterruptedBackend(6), False)  # in generation 2
    assert len(evaluated) == 7  # the 7th candidate was being computed: it is not on file
    done = set(evaluated[:6])
    evaluated.clear()
    resumed = optimise(tmp_path / 'run', SerialBackend(), True)
    assert not done & set(evaluated) and len(evaluated) == 12 - 6 + len(fresh[1]['pareto']) + 2
    assert resumed == fresh
    evaluated.clear()
    assert optimise(tmp_path / 'run', SerialBackend(), True) == fresh
    assert evaluated == []


def test_the_command_writes_the_pareto_set_and_resumes_without_computing(tmp_path):
    out = tmp_path / 'optimise'
    command = [sys.executable, '-m', 'valve_sim.commands.cli', 'optimise',
               '--design', 'd_c=±5%', '--minimise', 'P_1_percent',
               '--maximise', 'r_d', '--tolerance', 'd_c=±5um', '--limits', 'P_1_percent<=20',
               '--yield', '90%', '--samples', '4', '--confirm-samples', '8',
               '--population', '4', '--generations', '2', '--workers', '1', '--out', str(out)]
    first = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    assert re.search(r'optimise: generation 2/2 \([\d,]+ runs spent, [\d,]+ saved\): 8/8 '
                     r'candidates \(100 %\).*ETA', first.stderr)
    assert re.search(r'runs: search [\d,]+ \([\d,]+ saved .*\), confirmation 27 \(3 designs\)',
                     first.stdout)
    summary = json.loads((out / 'pareto.json').read_text())
    assert summary['candidates_evaluated'] == 8 and summary['pareto']
    for entry in summary['pareto']:
        assert 0.0 <= entry['confirmed_yield']['ci95'][0] <= entry['confirmed_yield']['fraction']
        loaded = load_parameters(out / entry['parameter_file'])
        params, settings = loaded.params, loaded.settings
        assert params[D_C] == entry['design'][D_C]
        assert settings['preset_pressure'] == summary['problem']['preset_pressure']
    with open(out / 'pareto.csv') as stream:
        assert len(list(csv.DictReader(stream))) == len(summary['pareto'])
    assert (out / 'pareto_front.png').exists() and (out / 'distributions.png').exists()
    assert set(summary['baselines']) == {'reference', 'table2'}
    before = (out / 'pareto.json').read_text()
    again = subprocess.run(command + ['--resume'], capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert 'resumed: 8 of 8 candidates read' in again.stderr and 'confirming' not in again.stderr
    assert (out / 'pareto.json').read_text() == before


GOOD = ['--design', 'd_c=±20%', '--minimise', 'P_1_percent', '--tolerance', 'd_c=±5um']


@pytest.mark.parametrize(
    'change, message',
    [
        (['--design', 'd_c=1.2e-3:0.8e-3'], "'d_c=1.2e-3:0.8e-3': the range must have LO < HI"),
        (['--design', 'd_c=0.8e-3'], "--design: 'd_c=0.8e-3': SPEC must be"),
        (['--design', 'x_y=1:2'], "unknown parameter 'x_y'"),
        (['--design', 'd_c=0:1e-3'], 'leave the limits of damping_orifice_diameter'),
        (['--design', 'd_c=±20%,d_c=±10%'], 'given twice: damping_orifice_diameter'),
        (['--design', 'y_0=±10%'], 'design it with --frozen-preload'),
        (['--limits', 'P_9<=1'], "limit 'P_9<=1': expected MEASURE<=VALUE"),
        (['--limits', 'r_d<<0.8'], "limit 'r_d<<0.8'"),
        (['--minimise', 'P_9'], "--minimise 'P_9': not a measure"),
        (['--tolerance', 'd_c=0.9e-3:1.1e-3'], 'tolerance must follow its value'),
        (['--tolerance', 'k_p=±5um'], 'um is a length, and pilot_spring_stiffness is in N/m'),
        (['--yield', '1.5'], "--yield '1.5': expected a fraction in (0, 1]"),
        (['--samples', '100'], 'the Sobol sampler needs a power of two samples, not 100'),
    ],
)
def test_bad_bounds_limits_and_settings_get_one_line_errors(change, message, capsys, tmp_path):
    options = dict(zip(GOOD[::2], GOOD[1::2]))
    options.update(zip(change[::2], change[1::2]))
    out = tmp_path / 'never'
    argv = ['optimise', *(part for pair in options.items() for part in pair), '--out', str(out)]
    assert main(argv) == 1
    error = capsys.readouterr().err
    assert error.startswith('valve-sim optimise: error: ') and error.count('\n') == 1, error
    assert message in error
    assert not out.exists()


def test_tolerances_in_a_machine_shops_units(reference):
    (distribution,) = parse_variations(['d_c=±5um'], reference)
    assert (distribution.a, distribution.b) == pytest.approx((0.995e-3, 1.005e-3))
    (distribution,) = parse_variations(['d_c=+-0.01mm'], reference)
    assert (distribution.a, distribution.b) == pytest.approx((0.99e-3, 1.01e-3))


def test_pareto_front():
    points = [[1, 5], [2, 2], [3, 3], [5, 1], [2, 2], [4, 4]]
    assert pareto_front(points) == [0, 1, 3, 4]
    assert pareto_front([[3], [1], [2]]) == [1]


def test_a_parameter_file_applies_to_the_node_in_any_namespace(reference, tmp_path):
    problem = problem_of(reference, ['d_c=±20%'], ['P_1_percent'], [], ['d_c=±5um'])
    text = parameter_file_text(problem, {D_C: 1.1e-3}, 'test')
    assert '\n/**/relief_valve:\n  ros__parameters:\n' in text
    path = tmp_path / 'design.yaml'
    path.write_text(text)
    loaded = load_parameters(path)
    params, settings = loaded.params, loaded.settings
    assert params == {**reference, D_C: 1.1e-3}
    assert settings['preset_pressure'] == problem.preset_pressure


def test_no_feasible_design_is_said_and_fails(tmp_path):
    out = tmp_path / 'optimise'
    result = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'optimise', '--design', 'd_c=±5%',
         '--minimise', 'P_1_percent', '--tolerance', 'd_c=±5um', '--limits', 'T_s_ms<=1',
         '--samples', '4', '--confirm-samples', '4', '--population', '4', '--generations', '1',
         '--workers', '1', '--out', str(out)],
        capture_output=True, text=True, timeout=600)
    assert result.returncode == 1, result.stderr
    assert 'no candidate meets the limits and the required yield' in result.stdout
    assert json.loads((out / 'pareto.json').read_text())['pareto'] == []
