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
spread over all cores. Writes into --out:
  sensitivity.csv   parameter, variation_percent, the six measures
  table3.csv        measure, table1, table2, relative_change_percent
  figure06_m_m.png ... figure12_k_p.png, figure08_pilot_poppet.png, figure13_P_o.png
As in the paper, the preset is not readjusted between cases (the measures are
relative to each case's own initial pressure).
"""

from concurrent.futures import as_completed, ProcessPoolExecutor
import csv
import os
from pathlib import Path
import sys

import numpy as np
from valve_sim.analysis.measures import MEASURE_NAMES, step_measures
from valve_sim.analysis.paper import (
    REFERENCE_SCENARIO,
    STUDY_PARAMETERS,
    STUDY_VARIATIONS,
    TABLE2_CHANGES,
)
from valve_sim.commands.simulate import add_parameter_arguments, load_from_arguments
from valve_sim.core.integrator import OverpressureError
from valve_sim.core.parameters import scaled
from valve_sim.core.simulation import simulate
from valve_sim.core.steady_state import SteadyStateError


FIGURE_NUMBERS = {'m_m': 6, 'm_p': 7, 'V_p': 9, 'V_c': 10, 'd_c': 11, 'k_p': 12}
POPPET_SAMPLE_INTERVAL = 1e-4  # [s] for Figure 8's waveforms


def add_arguments(parser):
    add_parameter_arguments(parser)
    parser.add_argument(
        '--out', required=True, metavar='DIR', help='output folder (created if missing)'
    )
    parser.add_argument('--step-size', type=float, metavar='S', help='RK4 step [s] (default 1e-5)')
    parser.add_argument(
        '--jobs',
        type=int,
        default=os.cpu_count() or 1,
        metavar='N',
        help='parallel processes (default: all cores)',
    )


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


def run_case(params, changes, step_size):
    """
    Measures (dict) of one case and its poppet waveform (time, y) for Figure 8.

    A case whose valve leaves the physical limits (valve_sim.core.limits: d_c -20 %
    cannot open its main valve and would sit at 40 MPa, beyond burst_pressure) has
    every measure undefined, the refusal as the reason, and no waveform.
    """
    try:
        waveforms = simulate(
            scaled(params, changes), REFERENCE_SCENARIO, step_size, POPPET_SAMPLE_INTERVAL
        )
    except (SteadyStateError, OverpressureError) as error:
        reason = f'beyond the physical limits: {error}'
        measures = dict.fromkeys(MEASURE_NAMES)
        measures.update(reasons=dict.fromkeys(MEASURE_NAMES, reason), details={})
        return measures, (np.empty(0), np.empty(0))
    measures = step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        REFERENCE_SCENARIO.step_time,
    )
    return measures.as_dict(), (waveforms.time, waveforms['poppet_displacement'])


def run_all(params, step_size, jobs, progress=print):
    """Run every case in parallel; returns {label: (measures, poppet_waveform)}."""
    cases = study_cases()
    results = {}
    with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
        futures = {
            pool.submit(run_case, params, changes, step_size): label for label, changes in cases
        }
        for done, future in enumerate(as_completed(futures), 1):
            label = futures[future]
            results[label] = future.result()
            measures = results[label][0]
            summary = ', '.join(
                f'{name}={measures[name]:.4g}' if measures[name] is not None else f'{name}=-'
                for name in MEASURE_NAMES
            )
            progress(f'[{done:2d}/{len(cases)}] {label:<14} {summary}')
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
            percent: results[f'm_p {percent:+d} %' if percent else 'reference'][1]
            for percent in STUDY_VARIATIONS
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
    step_size = settings['step_size']
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f'parameter study: {len(study_cases())} runs on {args.jobs} processes', file=sys.stderr)
    results = run_all(
        params,
        step_size,
        args.jobs,
        progress=lambda line: print(line, file=sys.stderr, flush=True),
    )
    write_sensitivity(out / 'sensitivity.csv', results)
    write_table3(out / 'table3.csv', results)
    write_figures(out, results)
    for label, (measures, _) in results.items():
        for name, reason in measures['reasons'].items():
            print(f'note: {label}: {name}: {reason}', file=sys.stderr)
    print(f'wrote {out}/sensitivity.csv, {out}/table3.csv and Figures 6-13 as PNG')
    return 0
