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
Reproduce the paper's parameter study: Figures 6-13 and Table 3.

m_m, m_p, V_p, V_c, d_c and k_p are varied one at a time by -20, -10, 0, +10 and
+20 % of their reference values (30 cases; the five 0 % cases are one run), and
the six together as in Table 2: 26 distinct runs of the paper's step test,
run in batches by the study runner (a local Dask cluster, --scheduler for an existing
one, a process pool without dask). Writes into --out:
  results.jsonl     one row per run as it completes (--resume completes a broken study)
  sensitivity.csv   parameter, variation_percent, the six measures
  table3.csv        measure, table1, table2, relative_change_percent
  figure06_m_m.png ... figure12_k_p.png, figure08_pilot_poppet.png, figure13_P_o.png
As in the paper, the preset is not readjusted between cases (the measures are
relative to each case's own initial pressure).
"""

import csv
from pathlib import Path
import sys

import numpy as np
from valve_sim.analysis.measures import MEASURE_NAMES
from valve_sim.analysis.paper import (
    REFERENCE_SCENARIO,
    STUDY_PARAMETERS,
    STUDY_VARIATIONS,
    TABLE2_CHANGES,
)
from valve_sim.analysis.study_runner import run_cases
from valve_sim.commands.simulate import add_parameter_arguments, load_from_arguments
from valve_sim.commands.study_backend import add_runner_arguments, open_backend
from valve_sim.core.parameters import scaled


FIGURE_NUMBERS = {'m_m': 6, 'm_p': 7, 'V_p': 9, 'V_c': 10, 'd_c': 11, 'k_p': 12}
FIGURE8_PARAMETER = 'm_p'  # Figure 8: the poppet waveforms of the m_p variations


def add_arguments(parser):
    add_parameter_arguments(parser)
    parser.add_argument(
        '--out', required=True, metavar='DIR', help='output folder (created if missing)'
    )
    parser.add_argument('--step-size', type=float, metavar='S', help='RK4 step [s] (default 1e-5)')
    add_runner_arguments(parser)


def study_cases():
    """[(label, {symbol: percent})]: the baseline, the one-at-a-time variations, Table 2."""
    cases = [('reference', {})]
    for symbol in STUDY_PARAMETERS:
        cases += [
            (f'{symbol} {percent:+d} %', {symbol: percent})
            for percent in STUDY_VARIATIONS
            if percent
        ]
    cases.append(('table2', dict(TABLE2_CHANGES)))
    return cases


def runner_cases(params, step_size):
    """Return the study's cases as the runner takes them, indexed in study_cases() order."""
    return [
        {
            'index': index,
            'params': scaled(params, changes),
            'preset_pressure': None,
            'scenario': REFERENCE_SCENARIO,
            'step_size': step_size,
            'record': ['poppet_displacement'] if set(changes) <= {FIGURE8_PARAMETER} else [],
        }
        for index, (_, changes) in enumerate(study_cases())
    ]


def run_all(params, step_size, backend, results_path, resume=False, progress_stream=sys.stderr):
    """
    Run every case on the backend; returns {label: (measures, poppet_waveform)}.

    measures: the six (None where undefined) with 'reasons' (and 'error' for a run
    that failed); poppet_waveform: (time, y) for Figure 8's cases, else None.
    """
    labels = [label for label, _ in study_cases()]
    rows, _ = run_cases(
        runner_cases(params, step_size),
        results_path,
        backend,
        resume,
        label='study',
        progress_stream=progress_stream,
    )
    results = {}
    for index, label in enumerate(labels):
        row = rows[index]
        measures = dict(row['measures'], reasons=dict(row['reasons']))
        if row['error']:
            measures['reasons'] = dict.fromkeys(MEASURE_NAMES, row['error'])
        waveforms = row.get('waveforms')
        poppet = (
            (np.asarray(waveforms['time']), np.asarray(waveforms['poppet_displacement']))
            if waveforms
            else None
        )
        results[label] = (measures, poppet)
    return results


def _value(measures, name):
    return measures[name] if measures[name] is not None else ''


def write_sensitivity(path, results):
    with open(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(['parameter', 'variation_percent', *MEASURE_NAMES])
        for symbol in STUDY_PARAMETERS:
            for percent in STUDY_VARIATIONS:
                label = f'{symbol} {percent:+d} %' if percent else 'reference'
                writer.writerow(
                    [symbol, percent, *(_value(results[label][0], name) for name in MEASURE_NAMES)]
                )


def write_table3(path, results):
    table1, table2 = results['reference'][0], results['table2'][0]
    with open(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(['measure', 'table1', 'table2', 'relative_change_percent'])
        for name in MEASURE_NAMES:
            a, b = table1[name], table2[name]
            change = (b - a) / a * 100.0 if a not in (None, 0.0) and b is not None else ''
            writer.writerow([name, _value(table1, name), _value(table2, name), change])


def write_figures(out, results):
    from valve_sim.analysis.plotting import (
        plot_poppet_waveforms,
        plot_pressure_increment,
        plot_sensitivity,
    )

    for symbol in STUDY_PARAMETERS:
        series = {
            percent: results[f'{symbol} {percent:+d} %' if percent else 'reference'][0]
            for percent in STUDY_VARIATIONS
        }
        number = FIGURE_NUMBERS[symbol]
        plot_sensitivity(
            out / f'figure{number:02d}_{symbol}.png', symbol, series, f'Figure {number}'
        )
    plot_poppet_waveforms(
        out / 'figure08_pilot_poppet.png',
        {
            percent: waveform
            for percent in STUDY_VARIATIONS
            if (waveform := results[f'm_p {percent:+d} %' if percent else 'reference'][1])
        },
        REFERENCE_SCENARIO.step_time,
    )
    plot_pressure_increment(
        out / 'figure13_P_o.png',
        {
            symbol: {
                percent: results[f'{symbol} {percent:+d} %' if percent else 'reference'][0][
                    'P_o_percent'
                ]
                for percent in STUDY_VARIATIONS
            }
            for symbol in ('d_c', 'k_p')
        },
    )


def run(args):
    params, settings = load_from_arguments(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    backend = open_backend(args, 'study', pool_fallback=True)
    try:
        results = run_all(
            params, settings['step_size'], backend, out / 'results.jsonl', args.resume
        )
    finally:
        backend.close()
    write_sensitivity(out / 'sensitivity.csv', results)
    write_table3(out / 'table3.csv', results)
    write_figures(out, results)
    for label, (measures, _) in results.items():
        for name, reason in measures['reasons'].items():
            print(f'note: {label}: {name}: {reason}', file=sys.stderr)
    print(f'wrote {out}/sensitivity.csv, {out}/table3.csv and Figures 6-13 as PNG')
    return 0
