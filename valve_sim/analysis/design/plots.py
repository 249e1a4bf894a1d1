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
Figures of a robust optimisation: the Pareto front, and a design's measures against Table 2's.

Rows are analysis.design.robust_yield's candidate rows; the outcome is
analysis.design.optimisation.outcome_of's.
"""

from itertools import combinations

import numpy as np
from valve_sim.analysis.plotting import MEASURE_LABELS, plt, save_figure
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.analysis.studies.plots import _limit_lines
from valve_sim.analysis.studies.tolerances import parse_limits


def _objective_values(problem, rows, index):
    return np.array([
        np.nan if row.get('nominal') is None
        or row['nominal']['measures'][problem.objectives[index].measure] is None
        else row['nominal']['measures'][problem.objectives[index].measure]
        for row in rows
    ], dtype=float)


def plot_pareto_front(path, problem, records, outcome):
    """
    Every candidate's nominal objectives, the Pareto designs and the baselines.

    One panel per pair of objectives (one objective: against the candidate number).
    Grey: candidates that miss the yield or the limits; light brown: left with the
    yield undecided (dominated by a promising design, or open and not needed by the
    Pareto set); blue: feasible; black ringed:
    the Pareto set; green: the chosen design; red star: Table 2; black cross: the
    reference valve.
    """
    rows = [row for _, row in records]
    feasible = np.array([problem.feasible(row) for row in rows], dtype=bool)
    undecided = np.array([problem.undecided(row) for row in rows], dtype=bool)
    pareto = [row for _, row, _ in outcome['pareto']]
    chosen = outcome['chosen']
    count = len(problem.objectives)
    pairs = list(combinations(range(count), 2)) or [(None, 0)]
    columns = min(3, len(pairs))
    lines = -(-len(pairs) // columns)
    figure, axes = plt.subplots(lines, columns, figsize=(5.2 * columns, 4.4 * lines),
                                constrained_layout=True, squeeze=False)
    for axis, (i, j) in zip(axes.flat, pairs):
        def coordinates(selected, i=i, j=j):
            x = (np.array([row['index'] for row in selected], dtype=float) if i is None
                 else _objective_values(problem, selected, i))
            return x, _objective_values(problem, selected, j)
        x, y = coordinates(rows)
        missing = ~feasible & ~undecided
        axis.plot(x[missing], y[missing], '.', color='0.75', markersize=4,
                  label='misses yield or limits')
        if undecided.any():
            axis.plot(x[undecided], y[undecided], '.', color='tan', markersize=4,
                      label='yield undecided')
        axis.plot(x[feasible], y[feasible], '.', color='tab:blue', markersize=5,
                  label=f'meets yield {100 * problem.required_yield:g} %')
        px, py = coordinates(pareto)
        axis.plot(px, py, 'o', markerfacecolor='none', markeredgecolor='black', markersize=8,
                  label='Pareto set')
        if chosen is not None:
            axis.plot(px[chosen], py[chosen], 'o', color='tab:green', markersize=9,
                      label='chosen')
        for label, style in (('table2', 'r*'), ('reference', 'kx')):
            if label in outcome['baselines']:
                bx, by = coordinates([outcome['baselines'][label]])
                if i is None:
                    axis.axhline(by[0], color=style[0], linestyle=':', linewidth=1.0,
                                 label=label)
                else:
                    axis.plot(bx, by, style, markersize=11, label=label)
        names = [o.measure for o in problem.objectives]
        axis.set_xlabel('candidate' if i is None else f'{MEASURE_LABELS[names[i]]} '
                        f'({problem.objectives[i].sense})', fontsize=9)
        axis.set_ylabel(f'{MEASURE_LABELS[names[j]]} ({problem.objectives[j].sense})',
                        fontsize=9)
        axis.grid(True, alpha=0.3)
    for axis in list(axes.flat)[len(pairs):]:
        axis.set_visible(False)
    axes.flat[0].legend(fontsize=7)
    figure.suptitle(
        f'{len(rows)} candidates, nominal measures;\n{int(feasible.sum())} meet the limits and '
        f"the yield (Monte Carlo of {'' if problem.stop_alpha is None else 'up to '}"
        f'{problem.samples} valves)'
        + (f';\n{int(undecided.sum())} left undecided, not needed by the Pareto set'
           if undecided.any() else ''), fontsize=10)
    save_figure(figure, path, dpi=110)


def plot_distributions(path, problem, designs):
    """
    Empirical CDF of each measure over the sampled valves of each design, limits marked.

    designs: [(label, confirmation row with sample_rows)], e.g. the chosen design and
    Table 2 under the same tolerances; the legend gives each one's yield.
    """
    limits = parse_limits(','.join(problem.limits))
    figure, axes = plt.subplots(2, 3, figsize=(11, 6.5), constrained_layout=True)
    for (label, row), colour in zip(designs, ('tab:green', 'tab:red', 'tab:blue')):
        samples = row['sample_rows']
        low, high = row['ci95']
        legend = (f"{label}: yield {100 * row['yield']:.1f} % "
                  f'({100 * low:.1f}-{100 * high:.1f} %)')
        for axis, name in zip(axes.flat, MEASURE_NAMES):
            values = np.sort([r['measures'][name] for r in samples
                              if r['measures'][name] is not None])
            if values.size:
                axis.step(values, np.arange(1, values.size + 1) / len(samples), where='post',
                          color=colour, label=legend)
            nominal = row['nominal']['measures'][name]
            if nominal is not None:
                axis.axvline(nominal, color=colour, linestyle=':', linewidth=1.0)
    for axis, name in zip(axes.flat, MEASURE_NAMES):
        _limit_lines(axis, limits, name, vertical=True)
        axis.set_xlabel(MEASURE_LABELS[name], fontsize=9)
        axis.set_ylabel('fraction of valves')
        axis.set_ylim(0.0, 1.02)
        axis.grid(True, alpha=0.3)
    axes.flat[0].legend(fontsize=7, loc='lower right')
    figure.suptitle(
        f"The same tolerances ({', '.join(problem.tolerances)}), {designs[0][1]['samples']} "
        'valves each; dotted: the nominal valve, dashed: the limits', fontsize=9)
    save_figure(figure, path, dpi=110)
