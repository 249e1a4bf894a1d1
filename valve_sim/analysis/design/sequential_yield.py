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
Sequential yield: a candidate's valves sampled in rounds, stopped once its yield is decided.

The rounds are prefixes of the candidate's one draw of `samples` valves (the same
unit-cube points every candidate shares, tolerances.draw): the valves run after k
rounds are the first rounds[k] of the full sample, so a valve is the same whether
it runs in one round or several. Rounds double from `first` (16) up to the full
sample; with Sobol points a power-of-two prefix is itself a balanced Sobol sample.

After each round but the last (verdict):
  'below'  the failures so far already exceed those the full sample may have
           (passed / samples < required however the rest go): the full sample's
           own verdict, reached early (curtailment, no error of its own); or
           the yield's two-sided Clopper-Pearson interval, taken at confidence
           1 - alpha / looks (Bonferroni over the looks), lies below the required
           yield;
  'above'  that interval's lower end is at or above the required yield;
otherwise the next round runs. With the samples taken as independent, the chance
that a candidate whose true yield meets the target is stopped 'below' by an
interval is at most alpha / 2, and that one whose true yield misses it is stopped
'above' at most alpha / 2 (the union bound over the looks). A candidate that no look
decides runs its full sample and is judged as without rounds: passed / samples
against the required yield. In a search three more verdicts leave the yield
undecided or need none:
  'nominal'    the nominal valve breaks a limit, decays too slowly, lacks an
               objective or cannot be set: infeasible whatever its yield, no sample runs;
  'dominated'  its nominal objectives are dominated by a promising design before it
               (one found feasible, or left open with a yield estimate that meets the
               target): it cannot enter the Pareto set while that design stands, so
               no sample runs;
  'open'       still undecided after the round that reaches `defer_after` valves:
               its sample continues only if the Pareto set needs it.
The optimiser ranks an open candidate on its estimate so far and a dominated one as
meeting the yield (it ranks behind the design that dominates it anyway). Neither
counts as meeting the yield: at the end of the search the Pareto set is resolved
(optimisation.resolve): the open and dominated candidates on the front of the
feasible and undecided ones run their rule to a verdict, without a front or a
deferral, until every design on that front is decided. So the Pareto set is the one
a search deciding every candidate would find among the same candidates, but for the
intervals' errors above.
A generation's candidates go to the workers longest first (longest_first): those whose
nominal valve passes with the widest margin to its limits, the likeliest to run every
round, start before the short ones, which fill the workers around them.
"""

from collections import Counter
from functools import partial

from valve_sim.analysis.studies.tolerances import parse_limits, yield_interval

FIRST_ROUND = 16  # valves in a candidate's first round
STOP_ALPHA = 0.05  # the chance of a wrong early stop, split over the looks
# Valves after which a search leaves an undecided candidate open: enough that an estimate
# meeting a 99 % target says a yield above 95 % (64 of 64: its one-sided 95 % bound), a
# quarter of the default 256.
DEFER_AFTER = 64
DECISIONS = ('nominal', 'below', 'above', 'dominated', 'open', 'full')
UNDECIDED = ('dominated', 'open')  # left for the resolution of the Pareto set


def rounds(samples, first=FIRST_ROUND):
    """Return the valve counts after each round: first, doubling, ending at samples."""
    counts, count = [], max(1, min(first, samples))
    while count < samples:
        counts.append(count)
        count *= 2
    return counts + [samples]


def look(passed, total, required_yield, alpha, looks):
    """Return 'below', 'above' or None: the yield decided at one of `looks` interim looks."""
    low, high = yield_interval(passed, total, 1.0 - alpha / looks)
    if high < required_yield:
        return 'below'
    if low >= required_yield:
        return 'above'
    return None


def verdict(passed, total, samples, required_yield, alpha, looks):
    """
    Return 'below', 'above' or None after an interim look at total of samples valves.

    'below' without an interval when the failures so far already rule out the full
    sample's passed / samples >= required_yield.
    """
    if curtailed(passed, total, samples, required_yield):
        return 'below'
    return look(passed, total, required_yield, alpha, looks)


def curtailed(passed, total, samples, required_yield):
    """Tell whether total valves of samples, passed of them, rule out the yield required."""
    return (samples - (total - passed)) / samples < required_yield


def suspects(rows, count=FIRST_ROUND):
    """
    Return the numbers of the count valves that failed most often in rows (fewer if fewer did).

    All candidates share their valves' unit-cube points, and a design near a limit fails
    on the same few points as its neighbours: run first, they find its failures soonest.
    Rows give their valves' numbers (valves) or run a prefix (pass in sample order).
    """
    failed = Counter()
    for row in rows:
        numbers = row.get('valves') or range(len(row['pass']))
        failed.update(number for number, verdict in zip(numbers, row['pass']) if verdict == '0')
    return sorted(sorted(failed, key=lambda number: (-failed[number], number))[:count])


def dominated(point, front):
    """Tell whether a point (objective values to minimise) is dominated by one of front."""
    return any(
        all(f <= p for f, p in zip(other, point)) and any(f < p for f, p in zip(other, point))
        for other in front
    )


def runs_of(row):
    """Return the runs a candidate row took: its sampled valves and its nominal one."""
    return row.get('runs', row['samples'] + 1)


def planned_runs_of(row):
    """Return the runs the row's candidate would take with its full sample, nominal included."""
    return row.get('planned_samples', row['samples']) + 1


class RunTally:
    """The runs a search spent, and saved against full samples; said in its progress line."""

    def __init__(self, progress):
        self.progress, self.spent, self.saved, self.counted = progress, 0, 0, set()
        self.generation = progress.label

    def add(self, rows):
        """Count candidate rows (each once, by index) and restate the progress label."""
        for row in rows:
            if row['index'] not in self.counted:
                self.counted.add(row['index'])
                self.spent += runs_of(row)
                self.saved += planned_runs_of(row) - runs_of(row)
        self.progress.label = (
            f'{self.generation} ({self.spent:,} runs spent, {self.saved:,} saved)'
        )

    def counting(self, backend):
        """Return backend with every batch of rows counted as it arrives."""
        return _CountingBackend(backend, self)


class _Wrapped:
    """A backend that passes everything but run() on to the backend it wraps."""

    def __init__(self, backend):
        self.backend = backend

    def __getattr__(self, name):
        return getattr(self.backend, name)


class _CountingBackend(_Wrapped):
    """A backend whose batches of rows a RunTally counts before the runner sees them."""

    def __init__(self, backend, tally):
        super().__init__(backend)
        self.tally = tally

    def run(self, evaluate, batches):
        for rows in self.backend.run(evaluate, batches):
            self.tally.add(rows)
            yield rows


def objective_point(case, nominal_row):
    """Return the nominal valve's objective values to minimise, or None if one is missing."""
    measures = nominal_row['measures']
    point = [measures.get(measure) for measure, _ in case['objectives']]
    if None in point:
        return None
    return [v if sense == 'minimise' else -v for v, (_, sense) in zip(point, case['objectives'])]


def longest_first(backend, evaluate):
    """
    Return backend submitting the candidates likeliest to run many rounds first.

    evaluate: nominal_stage's; without its nominal rows, backend as it is. A candidate
    whose nominal valve passes with the widest margin to its limits is the likeliest to
    run its full sample (a chain of rounds), so it starts first and the short ones fill
    the workers around it (longest processing time first). Only the order of the
    batches changes: a row does not depend on when it runs.
    """
    nominals = getattr(evaluate, 'keywords', {}).get('nominals')
    return backend if not nominals else _Ordered(backend, partial(_expected_rounds, nominals))


def _expected_rounds(nominals, batch):
    """Return the sort key of a batch of cases: its likeliest longest candidate's."""
    return max(_candidate_key(case, nominals.get(case['index'])) for case in batch)


def _candidate_key(case, nominal):
    """(1 sampled, 0 no samples: out of spec or dominated; then the nominal's margin)."""
    row = nominal[1] if nominal else None
    point = objective_point(case, row) if row and row['pass'] else None
    if point is None or dominated(point, case['front']):
        return (0, 0.0)
    margins = []
    for limit in parse_limits(','.join(case['limits'])):
        value, scale = row['measures'][limit.measure], abs(limit.value) or 1.0
        margins.append((limit.value - value if '<' in limit.operator else value - limit.value)
                       / scale)
    return (1, min(margins, default=0.0))


class _Ordered(_Wrapped):
    """A backend whose batches go out sorted by key, the largest first."""

    def __init__(self, backend, key):
        super().__init__(backend)
        self.key = key

    def run(self, evaluate, batches):
        return self.backend.run(evaluate, sorted(batches, key=self.key, reverse=True))
