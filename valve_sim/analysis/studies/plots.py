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
Figures of the sampled studies: tolerance distributions and Sobol indices.

Rows are the study runner's (measures, error); limits are tolerances.Limit.
"""

import numpy as np
from valve_sim.analysis.plotting import MEASURE_LABELS, plt, save_figure
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.analysis.studies.tolerances import passes


# Parameter units shown in a unit a person reads: (SI unit, largest |value| below) ->
# (factor, shown unit). 0.00098 m is shown as 0.98 mm, 158000 N/m as 158 N/mm.
DISPLAY_UNITS = {
    'm': ((1e-3, 1e6, 'µm'), (1.0, 1e3, 'mm')),
    'N/m': ((float('inf'), 1e-3, 'N/mm'),),
    'Pa': ((float('inf'), 1e-6, 'MPa'),),
    'kg': ((1.0, 1e3, 'g'),),
    'm^3': ((1e-3, 1e6, 'cm³'),),
}


def display_unit(unit, values):
    """Return (factor, unit) to show values [unit] with: mm or µm for m, N/mm, MPa, g, cm³."""
    largest = float(np.max(np.abs(values))) if np.size(values) else 0.0
    for below, factor, shown in DISPLAY_UNITS.get(unit, ()):
        if largest < below:
            return factor, shown
    return 1.0, unit


def _limit_lines(axis, limits, name, vertical):
    """Mark each limit of measure name with a dashed line and its label beside the line."""
    for limit in limits:
        if limit.measure == name:
            line = axis.axvline if vertical else axis.axhline
            line(limit.value, color='tab:red', linestyle='--', linewidth=1.0)
            axis.annotate(
                str(limit),
                (limit.value, 0.02) if vertical else (0.02, limit.value),
                xycoords=('data', 'axes fraction') if vertical else ('axes fraction', 'data'),
                xytext=(3, 0) if vertical else (0, 3),  # beside the line, not over it
                textcoords='offset points',
                horizontalalignment='left',
                verticalalignment='bottom',
                color='tab:red',
                fontsize=7,
                rotation=90 if vertical else 0,
            )


def plot_measure_cdfs(path, rows, limits, subtitle):
    """Empirical CDF of each measure over the samples, limits marked."""
    figure, axes = plt.subplots(2, 3, figsize=(11, 6.5), constrained_layout=True)
    for axis, name in zip(axes.flat, MEASURE_NAMES):
        values = np.sort([r['measures'][name] for r in rows if r['measures'][name] is not None])
        if values.size:
            axis.step(values, np.arange(1, values.size + 1) / len(rows), where='post')
        undefined = len(rows) - values.size
        if undefined:
            axis.text(0.02, 0.9, f'{undefined} undefined', transform=axis.transAxes,
                      fontsize=8, color='tab:red')
        _limit_lines(axis, limits, name, vertical=True)
        axis.set_xlabel(MEASURE_LABELS[name], fontsize=9)
        axis.set_ylabel('fraction of valves')
        axis.set_ylim(0.0, 1.02)
        axis.grid(True, alpha=0.3)
    figure.suptitle(f'Tolerance study, {len(rows)} valves: {subtitle}', fontsize=9)
    save_figure(figure, path, dpi=110)


def plot_measures_against(path, name, unit, values, rows, limits):
    """
    Each measure against one varied parameter; passing valves blue, failing red.

    values [unit] are shown in display_unit()'s unit.
    """
    good = np.array([passes(row, limits) for row in rows])
    factor, shown_unit = display_unit(unit, values)
    values = np.asarray(values) * factor
    figure, axes = plt.subplots(2, 3, figsize=(11, 6.5), constrained_layout=True)
    for axis, measure in zip(axes.flat, MEASURE_NAMES):
        y = np.array([np.nan if r['measures'][measure] is None else r['measures'][measure]
                      for r in rows])
        for mask, colour, label in ((good, 'tab:blue', 'pass'), (~good, 'tab:red', 'fail')):
            if mask.any():
                axis.plot(values[mask], y[mask], '.', color=colour, markersize=4, label=label)
        _limit_lines(axis, limits, measure, vertical=False)
        axis.set_xlabel(f'{name} [{shown_unit}]', fontsize=9)
        axis.set_ylabel(MEASURE_LABELS[measure], fontsize=8)
        axis.grid(True, alpha=0.3)
    axes.flat[0].legend(fontsize=8)
    figure.suptitle(f'Measures against {name}', fontsize=10)
    save_figure(figure, path, dpi=110)


def plot_sobol_indices(path, measure, labels, indices):
    """
    Bar chart of first-order and total Sobol indices with their confidence intervals.

    indices: {'S1', 'S1_conf', 'ST', 'ST_conf'} arrays in the order of labels.
    """
    figure, axis = plt.subplots(figsize=(7, 4), constrained_layout=True)
    x = np.arange(len(labels))
    axis.bar(x - 0.2, indices['S1'], 0.4, yerr=indices['S1_conf'], capsize=3,
             label='first order S_1', color='tab:blue')
    axis.bar(x + 0.2, indices['ST'], 0.4, yerr=indices['ST_conf'], capsize=3,
             label='total S_T', color='tab:orange')
    axis.set_xticks(x, labels)
    axis.set_ylabel('Sobol index [-]')
    axis.set_title(f'Global sensitivity of {MEASURE_LABELS.get(measure, measure)}', fontsize=10)
    axis.axhline(0.0, color='0.5', linewidth=0.8)
    axis.grid(True, axis='y', alpha=0.3)
    axis.legend(fontsize=8)
    save_figure(figure, path, dpi=110)
