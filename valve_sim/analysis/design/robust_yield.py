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
The yield of one design under its machining tolerances: a whole Monte Carlo as one work unit.

A candidate case is a study-runner case (analysis.studies.runner) whose work is the
Monte Carlo of one design:
  index, label     bookkeeping (unique index within its results file)
  params           the complete parameter set the design is applied to (SI)
  design           {parameter name: value} of the candidate
  protocol         'held-preset' or 'frozen-preload' (analysis.studies.cases.PROTOCOLS)
  preset_pressure  [Pa] the preset the design is set to (held preset), else None
  tolerances       variation texts (analysis.studies.tolerances), stated about the design's values
  samples, sampler, seed   the Monte Carlo's points (analysis.studies.tolerances.draw)
  limits           limit texts ('P_1_percent<=3.2'); min_decay_rate [1/s] or None
  scenario, step_size
  keep_samples     whether the row keeps every sampled valve's row (for figures)
  stop_alpha       the sequential rule's alpha (analysis.design.sequential_yield), or None:
                   every valve runs, as in the confirmation
  first_round, required_yield, objectives ([measure, sense] pairs), front (the
                   objective points, to minimise, of the promising designs so far:
                   a candidate they dominate runs no sample), defer_after (valves after
                   which an undecided candidate is left open, or None)

evaluate_candidates(cases) -> rows is the work unit. For each candidate it loads the
nominal valve as `valve-sim ... --params FILE` loads the design's parameter file
(design.report.write_parameter_file: the values, then preset_pressure sets the
pilot spring preload), draws the sampled valves about it as `valve-sim tolerance`
does (same distributions, sampler and seed, each valve set to the nominal valve's
cracking pressure), runs the nominal valve, and then the samples in rounds through
studies.runner.evaluate_batch, stopping as analysis.design.sequential_yield decides (a
row does not depend on its batch, so a valve is judged the same in any round). On a
Dask worker a round of more than SPLIT_VALVES valves is split into tasks of that many,
which the other workers take up: a generation then does not wait for one worker to
run a candidate's whole sample alone.

nominal_stage(evaluate, cases, backend) runs the nominal valves of a generation's
candidates first, together, one batch per worker (nominal_rows; no more batches than
groups of NOMINAL_GROUP valves): the lanes kernel runs LANES valves a call, so a lone
nominal valve costs about as much as a group of them. Each candidate then takes its
nominal valve and row from that stage (the same row it would have computed alone) and
draws its samples only if it samples at all.

check_candidate_row(row) checks a row read back from a results file (--resume) before
it is used: the keys the optimisation reads, with the types evaluate_candidate gives them.

A sampled valve passes when its run meets every limit (tolerances.passes) and, with
min_decay_rate, every linear mode decays at least that fast at both flows of the
test (core.linear.slowest_decay_rate; the default 3 1/s is 95 % within the measures'
1 s window, the stability calibrate asks of Table 2). The yield is passed / samples
with its Clopper-Pearson interval (tolerances.yield_interval).
"""

from functools import partial
import sys

from valve_sim.analysis.design.sequential_yield import (
    curtailed,
    DECISIONS,
    dominated,
    objective_point,
    rounds,
    verdict,
)
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP
from valve_sim.analysis.steps.measures import WINDOW
from valve_sim.analysis.studies.cases import preset_protocol, sample_cases, StudyCase
from valve_sim.analysis.studies.tolerances import (
    draw,
    parse_limits,
    parse_variations,
    passes,
    summarise,
    yield_interval,
)
from valve_sim.core.errors import InputFileError, MODEL_ERRORS
from valve_sim.core.input_files import shown
from valve_sim.core.parameters import validate


MIN_DECAY_RATE = 3.0 / WINDOW  # [1/s] a mode decays by 95 % (e^-3) within the window
DECAY_FAILURE = 'a mode decays too slowly'
# Valves per task when a candidate's round is split over a Dask cluster's workers: a
# multiple of the lanes kernel's LANES (16), large enough that a task's overhead is small.
SPLIT_VALVES = 32
# The lanes kernel's LANES: the nominal stage makes no more batches than groups of this many.
NOMINAL_GROUP = 16


def nominal_valve(case):
    """Return the validated nominal parameters of a candidate, set to its preset."""
    params = validate({**case['params'], **case['design']})
    if case['protocol'] == 'held-preset':
        from valve_sim.core.steady_state import with_preset_pressure

        params = with_preset_pressure(params, case['preset_pressure'])
    return params


def decay_rate(params, row, scenario):
    """Return the slowest decay rate [1/s] of a run's valve as it was set, or None."""
    if row['error'] is not None:
        return None
    from valve_sim.core.linear import slowest_decay_rate

    try:
        return slowest_decay_rate(
            {**params, 'pilot_spring_preload': row['pilot_spring_preload']},
            (scenario.initial_flow, scenario.final_flow),
        )
    except MODEL_ERRORS:
        return None


def decays(row, min_decay_rate):
    """Tell whether a run's valve (a row with its decay_rate) meets min_decay_rate (or None)."""
    return min_decay_rate is None or (
        row['decay_rate'] is not None and row['decay_rate'] >= min_decay_rate
    )


def valve_passes(row, limits, min_decay_rate):
    """Tell whether a run's valve meets every limit and the decay rate."""
    return passes(row, limits) and decays(row, min_decay_rate)


def evaluate_candidates(cases, nominals=None):
    """
    Return the rows of candidate cases, in their order (the work unit of a backend).

    nominals: {case index: (nominal valve, its row)} from nominal_rows (the nominal
    stage), or None.
    """
    nominals = nominals or {}
    return [evaluate_candidate(case, nominals.get(case['index'])) for case in cases]


def nominal_stage(evaluate, cases, backend):
    """
    Return evaluate with the nominal valves of cases run beforehand, in one batch per worker.

    No more batches than groups of NOMINAL_GROUP valves: a batch of fewer valves than
    the lanes kernel advances at once costs a whole kernel call. Only for
    evaluate_candidates (another evaluate, a test's, is returned as it is).
    """
    if evaluate is not evaluate_candidates or not cases:
        return evaluate
    parts = max(1, min(backend.workers, -(-len(cases) // NOMINAL_GROUP)))
    size = -(-len(cases) // parts)
    batches = [cases[i:i + size] for i in range(0, len(cases), size)]
    nominals = {}
    for part in backend.run(nominal_rows, batches):
        nominals.update(part)
    return partial(evaluate_candidates, nominals=nominals)


def nominal_rows(cases):
    """
    Return {case index: (nominal valve, its row)} of candidate cases, run as one batch.

    The nominal valve is nominal_valve's parameters. A candidate whose nominal valve
    cannot be set has none (it says why itself).
    """
    valves, owners = [], []
    for case in cases:
        try:
            nominal = nominal_valve(case)
            valves.append(_nominal_run(case, nominal, len(valves)))
        except MODEL_ERRORS:
            continue
        owners.append((case, nominal))
    rows = _batch_rows(valves)
    return {
        case['index']: (
            nominal,
            _judged(case, parse_limits(','.join(case['limits'])), valve, row)
            | {'index': case['samples']},
        )
        for (case, nominal), valve, row in zip(owners, valves, rows)
    }


def _nominal_run(case, nominal, index):
    """Return the runner case of a candidate's nominal valve (nominal: nominal_valve's)."""
    preset, _ = preset_protocol(case['protocol'], nominal)
    return StudyCase(index, nominal, preset, REFERENCE_FLOW_STEP, case['step_size'])


def evaluate_candidate(case, nominal_run=None):
    """
    Return the row of one candidate: its nominal measures, the yield and its interval.

    row: index, label, design, error (the nominal valve could not be set: then no
    sample runs), preset_pressure (the sampled valves'), nominal (the runner's row of
    the nominal valve with decay_rate and pass), samples (the valves run),
    planned_samples, runs (nominal included), decision (analysis.design.sequential_yield),
    passed, yield, ci95, pass (one '1' or '0' per valve run, in sample order),
    failures (per limit, failed runs, slow decay), percentiles of the measures over
    the valves run, and sample_rows (every sampled valve's row, with its sampled
    values) when keep_samples. Without stop_alpha every valve runs, whatever the
    nominal valve does. With suspects (valve numbers, resolving) those valves run
    first: if their failures already rule out the yield the row is theirs ('below',
    valves: their numbers, pass in that order), else they are runs spent and the
    rounds go on as without them. nominal_run: (nominal valve, its row) from nominal_rows, or
    None: it is set and runs here.
    """
    planned = case['samples']
    row = {key: case[key] for key in ('index', 'label', 'design')}
    row.update(samples=0, planned_samples=planned, runs=0, decision='nominal')
    limits = parse_limits(','.join(case['limits']))
    try:
        nominal, nominal_row = nominal_run or (nominal_valve(case), None)
    except MODEL_ERRORS as error:
        return {**row, 'error': str(error), 'passed': 0, 'yield': 0.0,
                'ci95': yield_interval(0, planned), 'pass': ''}
    preset, _ = preset_protocol(case['protocol'], nominal)
    distributions = parse_variations(case['tolerances'], nominal)
    names = [d.name for d in distributions]
    if nominal_row is None:
        (nominal_row,) = _runs(case, limits, [_nominal_run(case, nominal, planned)])
    alpha = case.get('stop_alpha')
    point = objective_point(case, nominal_row)
    sample_rows, decision, values, tried, counts = [], 'nominal', [], [], []
    if alpha is not None and nominal_row['pass'] and point is not None and dominated(
            point, case['front']):
        decision = 'dominated'
    elif alpha is None or (nominal_row['pass'] and point is not None):
        values = draw(distributions, planned, case['seed'], case['sampler'])
        cases = sample_cases(nominal, names, values, preset, case['step_size'])
        counts = rounds(planned, case['first_round']) if alpha is not None else [planned]
        defer_after = case.get('defer_after')
        suspects = case.get('suspects') or []
        tried = _runs(case, limits, [cases[i] for i in suspects]) if suspects else []
        if tried and curtailed(sum(run['pass'] for run in tried), len(tried), planned,
                               case['required_yield']):
            sample_rows, decision, counts = tried, 'below', []
            values = [values[i] for i in suspects]
            row['valves'] = list(suspects)
        for number, count in enumerate(counts):
            sample_rows += _runs(case, limits, cases[len(sample_rows):count])
            decision = 'full'
            if number == len(counts) - 1:
                break
            passed = sum(run['pass'] for run in sample_rows)
            decision = verdict(passed, count, planned, case['required_yield'], alpha,
                               len(counts) - 1)
            if decision is None and defer_after is not None and count >= defer_after:
                decision = 'open'
            if decision is not None:
                break
    verdicts = [run['pass'] for run in sample_rows]
    passed, count = sum(verdicts), len(verdicts)
    summary = summarise(sample_rows, limits)
    slow = sum(1 for run in sample_rows
               if run['error'] is None and not decays(run, case['min_decay_rate']))
    row.update(
        error=None,
        preset_pressure=preset,
        nominal=nominal_row,
        samples=count,
        runs=count + 1 + (len(tried) if counts else 0),
        decision=decision,
        passed=passed,
        ci95=yield_interval(passed, count) if count else [0.0, 1.0],
        failures={**summary['failures'], DECAY_FAILURE: slow},
        percentiles=summary['percentiles'],
        **{'yield': passed / count if count else 0.0,
           'pass': ''.join('01'[v] for v in verdicts)},
    )
    if case['keep_samples']:
        for run, sample in zip(sample_rows, values):
            run['sample'] = dict(zip(names, map(float, sample)))
        row['sample_rows'] = sample_rows
    return row


def _runs(case, limits, valves):
    """
    Return the rows of valves (runner cases), with decay_rate and pass, in their order.

    On a Dask worker a round of more than SPLIT_VALVES valves goes out as tasks of
    SPLIT_VALVES each (worker_client: this task leaves its thread while it waits), so
    that a candidate's last rounds spread over the workers instead of holding up its
    generation; elsewhere (a process pool, this process) the round is one batch. A
    valve's row does not depend on its batch, so the rows are the same either way.
    """
    client = _dask_worker_client() if len(valves) > SPLIT_VALVES else None
    if client is None:
        return _judged_runs(case, limits, valves)
    chunks = [valves[i:i + SPLIT_VALVES] for i in range(0, len(valves), SPLIT_VALVES)]
    with client() as dask:
        futures = [dask.submit(_judged_runs, case, limits, chunk, pure=False, priority=1)
                   for chunk in chunks]
        return [run for rows in dask.gather(futures) for run in rows]


def _dask_worker_client():
    """Return distributed.worker_client when this runs as a Dask task, else None."""
    if 'distributed' not in sys.modules:  # no Dask in this process: not on a worker
        return None
    from distributed import get_worker, worker_client

    try:
        get_worker()
    except ValueError:
        return None
    return worker_client


def _judged_runs(case, limits, valves):
    """Run valves as one batch; return their rows with decay_rate and pass."""
    return [_judged(case, limits, valve, row)
            for valve, row in zip(valves, _batch_rows(valves))]


def _batch_rows(valves):
    from valve_sim.analysis.studies.runner import evaluate_batch  # numba: on the worker

    return evaluate_batch(valves)


def _judged(case, limits, valve, row):
    """Return a valve's row with its decay_rate and pass (limits: case's, parsed)."""
    rate = case['min_decay_rate']
    row['decay_rate'] = (
        decay_rate(valve.params, row, case['scenario']) if rate is not None else None
    )
    row['pass'] = valve_passes(row, limits, rate)
    return row


def check_candidate_row(row):
    """
    Raise InputFileError naming the key unless row is a candidate row as evaluate_candidate gives.

    The resume check of studies.results.read_results for the optimisation's results files:
    the nominal valve's row and every kept sample row are checked as the runner's rows.
    """
    from valve_sim.analysis.studies.results import check_row, is_number

    if not isinstance(row, dict):
        raise InputFileError(f'a row is a JSON object, got {shown(row)}')
    index, samples = row.get('index'), row.get('samples')
    for key, value in (('index', index), ('samples', samples), ('passed', row.get('passed'))):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise InputFileError(f"key '{key}' must be an integer >= 0, got {shown(value)}")
    if not isinstance(row.get('label'), str) or not isinstance(row.get('pass'), str):
        raise InputFileError("keys 'label' and 'pass' must be text")
    if row.get('decision', 'full') not in DECISIONS:
        raise InputFileError(f"key 'decision' must be one of {', '.join(DECISIONS)}")
    design = row.get('design')
    if not isinstance(design, dict) or not all(map(is_number, design.values())):
        raise InputFileError(
            f"key 'design' must map parameter names to numbers, got {shown(design)}"
        )
    ci95 = row.get('ci95')
    if not is_number(row.get('yield')) or not (
        isinstance(ci95, list) and len(ci95) == 2 and all(map(is_number, ci95))
    ):
        raise InputFileError("keys 'yield' and 'ci95' must be a number and two numbers")
    if row.get('error') is not None:
        if not isinstance(row['error'], str):
            raise InputFileError(f"key 'error' must be text or null, got {shown(row['error'])}")
        return
    nominal = row.get('nominal')
    _check_inner(check_row, nominal, 'nominal')
    decay = nominal.get('decay_rate')
    if not (decay is None or is_number(decay)) or not isinstance(nominal.get('pass'), bool):
        raise InputFileError("key 'nominal' must hold a decay_rate (a number or null) and a pass")
    for key in ('failures', 'percentiles'):
        if not isinstance(row.get(key), dict):
            raise InputFileError(f"key '{key}' must be a JSON object, got {shown(row.get(key))}")
    valves = row.get('valves', [])
    if not (isinstance(valves, list) and all(type(v) is int and v >= 0 for v in valves)):
        raise InputFileError("key 'valves' must list valve numbers (integers >= 0)")
    sample_rows = row.get('sample_rows', [])
    if not isinstance(sample_rows, list):
        raise InputFileError("key 'sample_rows' must list the sampled valves' rows")
    for number, sample_row in enumerate(sample_rows):
        _check_inner(check_row, sample_row, f'sample_rows[{number}]')


def _check_inner(check, row, key):
    """check(row) for a row inside a row: an InputFileError names the key it is under."""
    try:
        check(row)
    except InputFileError as error:
        raise InputFileError(f"key '{key}': {error}") from None
