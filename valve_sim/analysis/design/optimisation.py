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
Robust design optimisation: the best nominal response whose valves survive their tolerances.

The problem (RobustProblem): designed parameters with bounds, objectives on the
nominal valve's six measures (minimise or maximise), limits every valve must meet,
the machining tolerances about each design's values, and a required yield. Each
candidate design is one work unit of the study runner (analysis.design.robust_yield): its
nominal run and a quasi-random Monte Carlo of its tolerances, one batch of the lanes
kernel. A design is feasible when its nominal valve meets the limits (and decays),
its objectives exist, and its yield is at least the required yield.

search() runs NSGA-II (pymoo: constraint domination, so feasible designs rank first,
infeasible ones by their violation) generation by generation, with the designs in the
unit cube of the bounds and a Latin-hypercube first generation. Each generation's
nominal valves run first, a batch per worker (robust_yield.nominal_stage); its
candidates then go to the runner as one study, the likeliest long ones first
(sequential_yield.longest_first), OUT/generation_NNN.jsonl, each sampled only
as far as its verdict needs (analysis.design.sequential_yield: rounds, the nominal screen,
no sample where a promising design before it dominates it, left open after defer_after
valves). The optimiser is seeded, and the candidates of a generation follow only from
the rows of the ones before, so --resume replays it: every generation on file is read
(the runner checks that its fingerprint, hence every design and setting, is the same),
only missing candidates are computed. resolve() then decides the undecided candidates
the Pareto set needs, so that it is the set deciding every candidate would give, and
confirm() re-runs the Pareto designs and the two baselines
(the reference valve and the paper's Table 2) with more samples and an independent
seed, keeping every valve's row: the yield of a design picked for passing a Monte
Carlo is biased upward by that choice, a fresh sample is not.

Over 400 lines on purpose: the options of a robust design (design, objectives,
tolerances) are parsed beside the RobustProblem they define, its search, resolution and
confirmation.
"""

from dataclasses import dataclass
from pathlib import Path
import sys

import numpy as np
from valve_sim.analysis.design.robust_yield import (
    check_candidate_row,
    evaluate_candidates,
    MIN_DECAY_RATE,
    nominal_stage,
)
from valve_sim.analysis.design.sequential_yield import (
    DEFER_AFTER,
    dominated,
    FIRST_ROUND,
    longest_first,
    runs_of,
    RunTally,
    STOP_ALPHA,
    suspects,
    UNDECIDED,
)
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP, TABLE2_CHANGES
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.analysis.studies.results import fingerprint
from valve_sim.analysis.studies.runner import Progress, run_cases
from valve_sim.analysis.studies.tolerances import (
    follows_nominal,
    parse_variation,
    SAMPLERS,
    unit_samples,
)
from valve_sim.core.errors import ParameterError
from valve_sim.core.output_files import make_folder
from valve_sim.core.parameters import resolve_name, scaled


SENSES = ('minimise', 'maximise')
UNDEFINED = 1e30  # objective value the optimiser sees where a measure does not exist


def items(texts):
    """Return the comma-separated items of one or several option texts."""
    return [item.strip() for text in texts for item in text.split(',') if item.strip()]


def _no_repeats(names, what):
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ParameterError(f'{what} given twice: {", ".join(repeated)}')


def parse_design(texts, params, protocol='held-preset'):
    """
    NAME=LO:HI or NAME=±X% (of params' value) items into uniform Distributions: the bounds.

    ParameterError names a bad item: its form, LO >= HI, bounds outside the parameter's
    limits, a parameter given twice, or the preload under the held preset.
    """
    bounds = []
    for text in items(texts):
        try:
            bound = parse_variation(text, params)
        except ParameterError as error:
            raise ParameterError(f'--design: {str(error).replace("variation ", "", 1)}') from None
        if bound.kind != 'uniform':
            raise ParameterError(f'--design {text!r}: bounds are LO:HI or ±X% (of the nominal)')
        if bound.name == 'pilot_spring_preload' and protocol == 'held-preset':
            raise ParameterError(
                '--design: the held preset sets pilot_spring_preload in every valve; design it '
                'with --frozen-preload'
            )
        bounds.append(bound)
    if not bounds:
        raise ParameterError('no parameter to design: give --design NAME=LO:HI[,NAME=LO:HI...]')
    _no_repeats([b.name for b in bounds], 'designed parameter(s)')
    return bounds


@dataclass(frozen=True)
class Objective:
    """One measure of the nominal valve to minimise or maximise."""

    measure: str
    sense: str

    def signed(self, measures):
        """Return the value the optimiser minimises (None where the measure does not exist)."""
        value = measures.get(self.measure)
        return None if value is None else value if self.sense == 'minimise' else -value


def parse_objectives(minimise, maximise):
    """'P_1_percent,T_s_ms' texts for each sense into Objectives; ParameterError if bad."""
    objectives = [
        Objective(name, sense)
        for sense, texts in zip(SENSES, (minimise, maximise))
        for name in items(texts or [])
    ]
    for objective in objectives:
        if objective.measure not in MEASURE_NAMES:
            raise ParameterError(
                f'--{objective.sense} {objective.measure!r}: not a measure; the measures are '
                f'{", ".join(MEASURE_NAMES)}'
            )
    if not objectives:
        raise ParameterError('no objective: give --minimise and/or --maximise MEASURE[,...]')
    _no_repeats([o.measure for o in objectives], 'objective(s)')
    return objectives


def parse_tolerances(texts, params, design):
    """
    Tolerance items (analysis.studies.tolerances forms) checked against params; returns the texts.

    A designed parameter's tolerance must follow its value (±X%, ±Xum, ~N(S%) or ~N(S)):
    a fixed range would not move with the design.
    """
    texts = items(texts)
    designed = {bound.name for bound in design}
    names = []
    for text in texts:
        distribution = parse_variation(text, params)
        if distribution.name in designed and not follows_nominal(text):
            raise ParameterError(
                f"--tolerance {text!r}: a designed parameter's tolerance must follow its value: "
                '±X%, ±Xum (or mm), ~N(S%) or ~N(S)'
            )
        names.append(distribution.name)
    if not texts:
        raise ParameterError('no tolerance: give --tolerance NAME=±X%[,NAME=±Xum...]')
    _no_repeats(names, 'tolerance(s) of')
    return texts


def exact_text(limit):
    """Write a tolerances.Limit as text that parses back to its value (str() rounds it)."""
    return f'{limit.measure}{limit.operator}{limit.value!r}'


def parse_fraction(text, what):
    """'0.99' or '99%' -> 0.99, within (0, 1]; ParameterError otherwise."""
    number = text.strip()
    scale = 100.0 if number.endswith('%') else 1.0
    try:
        value = float(number.rstrip('%')) / scale
    except ValueError:
        value = float('nan')
    if not 0.0 < value <= 1.0:
        raise ParameterError(f'{what} {text!r}: expected a fraction in (0, 1], e.g. 0.99 or 99%')
    return value


@dataclass(frozen=True)
class RobustProblem:
    """Everything that decides a robust optimisation's candidates and their rows."""

    params: dict  # complete parameter set the designs are applied to (SI)
    design: tuple  # Distributions (uniform): the bounds of each designed parameter
    objectives: tuple  # Objectives
    limits: tuple  # texts of the limits every valve must meet
    tolerances: tuple  # variation texts, one per toleranced parameter
    required_yield: float
    preset_pressure: float  # [Pa] held preset, or None with the frozen preload
    protocol: str = 'held-preset'
    samples: int = 256
    sampler: str = 'sobol'
    seed: int = 0
    confirm_samples: int = 1024
    stop_alpha: float = STOP_ALPHA  # the sequential rule's (None: every valve of a candidate)
    first_round: int = FIRST_ROUND
    defer_after: int = DEFER_AFTER  # valves after which a search leaves a candidate open (None)
    min_decay_rate: float = MIN_DECAY_RATE  # [1/s], or None: no stability requirement
    step_size: float = 1e-5

    def check(self):
        """Raise ParameterError if a sample count does not suit the sampler, or alpha (0, 1)."""
        if self.defer_after is not None and self.defer_after < 1:
            raise ParameterError(f'--defer-after {self.defer_after!r}: at least 1 valve')
        if self.stop_alpha is not None and not 0.0 < self.stop_alpha < 1.0:
            raise ParameterError(f'--sequential {self.stop_alpha!r}: alpha must be in (0, 1)')
        if self.sampler not in SAMPLERS:
            raise ParameterError(f'unknown sampler {self.sampler!r}; known: {", ".join(SAMPLERS)}')
        for count in (self.samples, self.confirm_samples):
            if count:
                unit_samples(count, 1, self.seed, self.sampler)  # raises for a bad count
        return self

    def values(self, unit):
        """Return the design {name: value} at a point of the unit cube of the bounds."""
        return {b.name: float(b.values(u)) for b, u in zip(self.design, unit)}

    def case(self, index, label, design, confirming=False, front=(), resolving=False):
        """
        Return the runner case of a design; confirming: more samples, every row kept.

        front: the objective points of the promising designs so far (a candidate they
        dominate runs no sample); the confirmation samples every valve; resolving: the
        sequential rule alone, to a verdict (no front, nothing left open).
        """
        return {
            'index': index,
            'label': label,
            'params': self.params,
            'design': design,
            'protocol': self.protocol,
            'preset_pressure': self.preset_pressure,
            'tolerances': list(self.tolerances),
            'samples': self.confirm_samples if confirming else self.samples,
            'sampler': self.sampler,
            'seed': self.seed + 1 if confirming else self.seed,
            'limits': list(self.limits),
            'min_decay_rate': self.min_decay_rate,
            'scenario': REFERENCE_FLOW_STEP,
            'step_size': self.step_size,
            'keep_samples': confirming,
            'stop_alpha': None if confirming else self.stop_alpha,
            'first_round': self.first_round,
            'required_yield': self.required_yield,
            'objectives': [[o.measure, o.sense] for o in self.objectives],
            'front': [] if confirming else [list(point) for point in front],
            'defer_after': None if confirming or resolving else self.defer_after,
        }

    def nominal_ok(self, row):
        """Tell whether a row's nominal valve was set, meets the spec and has the objectives."""
        nominal = row.get('nominal')
        return (
            row['error'] is None
            and nominal['pass']
            and all(o.signed(nominal['measures']) is not None for o in self.objectives)
        )

    def feasible(self, row):
        """
        Tell whether a candidate meets everything asked: a nominal valve in spec, the yield.

        A candidate whose yield was left undecided (dominated, open) is not.
        """
        return (self.nominal_ok(row) and row['yield'] >= self.required_yield
                and row.get('decision') not in UNDECIDED)

    def undecided(self, row):
        """Tell whether a candidate with its nominal valve in spec has its yield undecided."""
        return self.nominal_ok(row) and row.get('decision') in UNDECIDED

    def promising(self, row):
        """Tell whether a candidate is feasible, or open with an estimate meeting the yield."""
        return self.feasible(row) or (self.nominal_ok(row) and row.get('decision') == 'open'
                                      and row['yield'] >= self.required_yield)

    def scores(self, row):
        """
        Return (objective values to minimise, constraint values <= 0 when met) for pymoo.

        A candidate dominated before any valve ran is ranked as meeting the yield: it
        ranks behind the design that dominates it anyway.
        """
        measures = (row.get('nominal') or {}).get('measures', {})
        values = [o.signed(measures) for o in self.objectives]
        presumed = row.get('decision') == 'dominated' and not row['samples']
        return (
            [UNDEFINED if v is None else v for v in values],
            [0.0 if presumed else self.required_yield - row['yield'],
             0.0 if self.nominal_ok(row) else 1.0],
        )

    def baselines(self):
        """Return [(label, design)]: the parameter file's valve, and it with Table 2's changes."""
        table2 = scaled(self.params, TABLE2_CHANGES)
        return [
            ('reference', {}),
            ('table2', {resolve_name(s): table2[resolve_name(s)] for s in TABLE2_CHANGES}),
        ]


def search(problem, backend, folder, population, generations, resume=False,
           evaluate=evaluate_candidates, stream=sys.stderr, batch_size=1, budget=None):
    """
    Run NSGA-II over the design space; return [(generation, row)] of every candidate.

    Each generation is a study of the runner in folder/generation_NNN.jsonl; without
    resume the folder's earlier results are removed first. Each generation's cases
    carry the objective points of the feasible designs before it (a candidate they
    dominate stops sampling early). budget [runs]: no generation starts once the runs
    spent plus the last generation's runs would pass it. Progress and an ETA in
    candidates, with the runs spent and saved, go to stream.
    """
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.core.evaluator import Evaluator
    from pymoo.core.problem import Problem
    from pymoo.operators.sampling.lhs import LHS
    from pymoo.problems.static import StaticProblem

    folder = make_folder(Path(folder))
    if not resume:
        for old in folder.glob('*.jsonl'):
            old.unlink()
    unit_problem = Problem(
        n_var=len(problem.design), n_obj=len(problem.objectives), n_ieq_constr=2, xl=0.0, xu=1.0
    )
    algorithm = NSGA2(pop_size=population, sampling=LHS())
    algorithm.setup(unit_problem, termination=('n_gen', generations), seed=problem.seed)
    progress = Progress('optimise', population * generations, 0, stream, unit='candidates')
    tally = RunTally(progress)
    records, generation, on_file, last = [], 0, 0, 0
    while algorithm.has_next():
        if budget is not None and generation and tally.spent + last > budget:
            _say(stream, f'optimise: budget of {budget:,} runs: {tally.spent:,} spent, the '
                 f'next generation would take about {last:,}; the search stops after '
                 f'generation {generation}')
            break
        generation += 1
        offspring = algorithm.ask()
        progress.total -= population - len(offspring)
        tally.generation = f'optimise: generation {generation}/{generations}'
        tally.add([])
        front = promising_front(problem, records)
        cases = [
            problem.case(len(records) + i, f'candidate {len(records) + i}', problem.values(x),
                         front=front)
            for i, x in enumerate(offspring.get('X'))
        ]
        path = folder / f'generation_{generation:03d}.jsonl'
        before = tally.spent
        staged = evaluate if resume else nominal_stage(evaluate, cases, backend)
        ordered = tally.counting(longest_first(backend, staged))
        rows, computed = _run(cases, path, ordered, resume, batch_size, staged, progress,
                              f'in generation {generation}')
        tally.add(rows.values())  # those read back from file
        last = tally.spent - before
        on_file += len(cases) - computed
        rows = [rows[case['index']] for case in cases]
        objectives, constraints = zip(*(problem.scores(row) for row in rows))
        Evaluator().eval(
            StaticProblem(unit_problem, F=np.array(objectives), G=np.array(constraints)), offspring
        )
        algorithm.tell(infills=offspring)
        records += [(generation, row) for row in rows]
    if on_file:
        _say(stream, f'optimise: resumed: {on_file} of {len(records)} candidates read from '
             f'{folder}, {len(records) - on_file} computed')
    return resolve(problem, records, backend, folder, resume, evaluate, stream, batch_size)


def pareto_front(points):
    """Return the indices of the points (rows to minimise) that no other point dominates."""
    points = [list(np.atleast_1d(point)) for point in points]
    return [i for i, point in enumerate(points) if not dominated(point, points)]


def front_of(problem, records, kept):
    """Return the indices in records of those kept(row) that no other kept one dominates."""
    chosen = [i for i, (_, row) in enumerate(records) if kept(row)]
    return [chosen[i] for i in pareto_front([problem.scores(records[i][1])[0] for i in chosen])]


def promising_front(problem, records):
    """Return the objective points (to minimise) of the promising, non-dominated records."""
    return [problem.scores(records[i][1])[0]
            for i in front_of(problem, records, problem.promising)]


def resolve(problem, records, backend, folder, resume=False, evaluate=evaluate_candidates,
            stream=sys.stderr, batch_size=1):
    """
    Return records with the undecided candidates the Pareto set needs decided.

    While the front of the feasible and the undecided (dominated, open) candidates
    holds undecided ones, those run the sequential rule alone to a verdict (from their
    first valve: the same valves and verdicts as before, then on), a study of the
    runner in folder/resolve_<fingerprint>.jsonl each time. The valves that failed
    most often in the candidates so far run first (sequential_yield.suspects): a
    candidate they already fail is decided 'below' by them alone, exactly as its full
    sample would decide it. A resolved row keeps the search's runs in its own and its
    search decision as search_decision. The feasible Pareto set is then the one deciding
    every candidate would give.
    """
    records, spent = list(records), 0
    while True:
        on_front = front_of(problem, records,
                            lambda row: problem.feasible(row) or problem.undecided(row))
        pending = [i for i in on_front if problem.undecided(records[i][1])]
        if not pending:
            break
        first = suspects([row for _, row in records])
        cases = [{**problem.case(records[i][1]['index'], records[i][1]['label'],
                                 records[i][1]['design'], resolving=True), 'suspects': first}
                 for i in pending]
        path = Path(folder) / f'resolve_{fingerprint(cases)}.jsonl'
        progress = Progress('optimise: resolving the Pareto set', len(cases), 0, stream,
                            unit='candidates')
        staged = evaluate if resume else nominal_stage(evaluate, cases, backend)
        rows, _ = _run(cases, path, backend, resume, batch_size, staged, progress,
                       'while resolving the Pareto set')
        for i, case in zip(pending, cases):
            generation, searched = records[i]
            resolved = rows[case['index']]
            spent += runs_of(resolved)
            records[i] = (generation, {**resolved, 'runs': runs_of(searched) + runs_of(resolved),
                                       'resolution_runs': runs_of(resolved),
                                       'search_decision': searched['decision']})
    if spent:
        _say(stream, f'optimise: the Pareto set resolved with {spent:,} runs')
    return records


def pareto_set(problem, records):
    """Return [(generation, row)] of the feasible candidates no other feasible one dominates."""
    front = [records[i] for i in front_of(problem, records, problem.feasible)]
    return sorted(front, key=lambda record: problem.scores(record[1])[0])


def confirm(problem, designs, backend, folder, resume=False, evaluate=evaluate_candidates,
            stream=sys.stderr, batch_size=1):
    """
    Return the rows of designs [(label, design)] under confirm_samples fresh samples.

    One study of the runner in folder/confirm_<fingerprint>.jsonl: a resumed run with
    the same designs reads it, other designs make another file.
    """
    cases = [problem.case(i, label, design, True) for i, (label, design) in enumerate(designs)]
    path = Path(folder) / f'confirm_{fingerprint(cases)}.jsonl'
    progress = Progress('optimise: confirming', len(cases), 0, stream, unit='designs')
    staged = evaluate if resume else nominal_stage(evaluate, cases, backend)
    rows, _ = _run(cases, path, backend, resume, batch_size, staged, progress,
                   'while confirming')
    return [rows[case['index']] for case in cases]


def choose(problem, rows):
    """
    Return the index in rows of the design meeting the yield closest to the ideal point.

    Each objective is scaled to [0, 1] over those rows (0 its best value); the chosen
    row has the smallest Euclidean norm. None if no row meets the yield.
    """
    meeting = [i for i, row in enumerate(rows) if problem.feasible(row)]
    if not meeting:
        return None
    values = np.array([problem.scores(rows[i])[0] for i in meeting], dtype=float)
    span = np.ptp(values, axis=0)
    scaled_values = (values - values.min(axis=0)) / np.where(span > 0, span, 1.0)
    return meeting[int(np.argmin(np.linalg.norm(scaled_values, axis=1)))]


def outcome_of(problem, records, backend, folder, resume, evaluate=evaluate_candidates,
               stream=sys.stderr, batch_size=1):
    """
    Confirm the Pareto set beside the baselines; return a dict for the report.

    pareto: [(generation, search row, confirmation row)]; baselines: {label:
    confirmation row}; chosen: index in pareto or None.
    """
    front = pareto_set(problem, records)
    if not problem.confirm_samples:
        return {'pareto': [(g, row, None) for g, row in front], 'baselines': {},
                'chosen': choose(problem, [row for _, row in front])}
    designs = [(row['label'], row['design']) for _, row in front] + problem.baselines()
    rows = confirm(problem, designs, backend, folder, resume, evaluate, stream, batch_size)
    pareto = [(g, row, confirmed) for (g, row), confirmed in zip(front, rows)]
    baselines = {label: row for (label, _), row in zip(designs[len(front):], rows[len(front):])}
    return {'pareto': pareto, 'baselines': baselines,
            'chosen': choose(problem, [confirmed for _, _, confirmed in pareto])}


def _run(cases, path, backend, resume, batch_size, evaluate, progress, when):
    """run_cases() with progress; an interruption says where the finished work is."""
    try:
        return run_cases(cases, path, backend, resume, batch_size, evaluate,
                         progress_stream=None, progress=progress, check=check_candidate_row)
    except BaseException:
        _say(progress.stream, f'optimise: stopped {when}; every finished candidate is saved in '
             f'{path.parent}: --resume continues from there')
        raise


def _say(stream, text):
    if stream is not None:
        print(text, file=stream, flush=True)
