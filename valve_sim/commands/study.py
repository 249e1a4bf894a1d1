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
the six together as in Table 2: 26 distinct runs of the paper's step test, run
in batches by the study runner (a local Dask cluster, --scheduler for an existing
one, a local process pool when dask is not installed).

PROTOCOL (--protocol; valve_sim.analysis.studies.cases.PROTOCOLS): how the preset is
treated between cases.
  held-preset     (default, the paper's) the pilot spring preload is re-solved in
                  every case so that the main valve cracks at the same preset
                  pressure, as a technician turns the adjusting screw back to 7 MPa;
  frozen-preload  every case keeps the preload of the parameter file, so a stiffer or
                  softer spring moves the preset with it.
The preset is the base parameter set's cracking pressure (7 MPa for
config/reference.yaml), or --preset-pressure. Every output names its protocol.

Writes into --out:
  results.jsonl     one row per run as it completes (--resume completes a broken study)
  sensitivity.csv   parameter, variation_percent, protocol, preset and initial state, the six
                    measures and envelope_decay_per_s (T_s's continuous companion)
  table3.csv        measure, table1, table2, relative_change_percent, protocol
  figure06_m_m.png ... figure12_k_p.png, figure08_pilot_poppet.png, figure13_P_o.png
A case without a step response (no steady state, no relief through the main
stage, divergence) has empty measures and its reason in the CSV.
"""

import csv
from pathlib import Path
import sys

from valve_sim.analysis.paper import REFERENCE_FLOW_STEP, STUDY_PARAMETERS, STUDY_VARIATIONS
from valve_sim.analysis.steps.measures import ENVELOPE_DECAY, MEASURE_NAMES
from valve_sim.analysis.studies.backend import open_backend
from valve_sim.analysis.studies.cases import PROTOCOLS, run_all, study_cases
from valve_sim.commands.options import (
    add_options,
    add_protocol_arguments,
    add_runner_arguments,
    load_from_arguments,
)
from valve_sim.core.output_files import make_folder, replacing

# The model's modules (numba, scipy) are imported in the functions that run it, so that
# `valve-sim study --help` stays quick.


FIGURE_NUMBERS = {'m_m': 6, 'm_p': 7, 'V_p': 9, 'V_c': 10, 'd_c': 11, 'k_p': 12}
# The six measures and T_s's continuous companion, the envelope's decay rate [1/s].
STUDY_MEASURES = (*MEASURE_NAMES, ENVELOPE_DECAY)
CASE_COLUMNS = (
    'protocol',
    'preset_pressure_Pa',
    'cracking_pressure_Pa',
    'pilot_spring_preload_m',
    'initial_supply_pressure_Pa',
    'initial_main_valve_displacement_m',
)


def add_arguments(parser):
    add_options(parser, '--params', '--set', '--preset-pressure', '--out')
    add_protocol_arguments(parser)
    add_options(parser, '--step-size')
    add_runner_arguments(parser)


def _label(symbol, percent):
    return f'{symbol} {percent:+d} %' if percent else 'reference'


def _value(measures, name):
    return measures[name] if measures.get(name) is not None else ''


def write_sensitivity(path, results):
    with replacing(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(
            ['parameter', 'variation_percent', *CASE_COLUMNS, *STUDY_MEASURES, 'reasons']
        )
        for symbol in STUDY_PARAMETERS:
            for percent in STUDY_VARIATIONS:
                result = results[_label(symbol, percent)]
                measures, case = result['measures'], result['case']
                reasons = '; '.join(f'{k}: {v}' for k, v in measures['reasons'].items())
                writer.writerow(
                    [
                        symbol,
                        percent,
                        *('' if case[c] is None else case[c] for c in CASE_COLUMNS),
                        *(_value(measures, name) for name in STUDY_MEASURES),
                        reasons,
                    ]
                )


def write_table3(path, results):
    table1, table2 = results['reference']['measures'], results['table2']['measures']
    protocol = results['reference']['case']['protocol']
    with replacing(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(['measure', 'table1', 'table2', 'relative_change_percent', 'protocol'])
        for name in STUDY_MEASURES:
            a, b = table1.get(name), table2.get(name)
            change = (b - a) / a * 100.0 if a not in (None, 0.0) and b is not None else ''
            writer.writerow([name, _value(table1, name), _value(table2, name), change, protocol])


def write_figures(out, results, protocol):
    from valve_sim.analysis.plotting import (
        plot_poppet_waveforms,
        plot_pressure_increment,
        plot_sensitivity,
    )

    for symbol in STUDY_PARAMETERS:
        series = {
            percent: results[_label(symbol, percent)]['measures'] for percent in STUDY_VARIATIONS
        }
        number = FIGURE_NUMBERS[symbol]
        plot_sensitivity(
            out / f'figure{number:02d}_{symbol}.png',
            symbol,
            series,
            f'Figure {number} ({protocol})',
        )
    plot_poppet_waveforms(
        out / 'figure08_pilot_poppet.png',
        {
            percent: results[_label('m_p', percent)]['poppet']
            for percent in STUDY_VARIATIONS
            if results[_label('m_p', percent)]['poppet'] is not None
        },
        REFERENCE_FLOW_STEP.step_time,
    )
    plot_pressure_increment(
        out / 'figure13_P_o.png',
        {
            symbol: {
                percent: results[_label(symbol, percent)]['measures']['P_o_percent']
                for percent in STUDY_VARIATIONS
            }
            for symbol in ('d_c', 'k_p')
        },
    )


def run(args):
    from valve_sim.core.steady_state import cracking_pressure

    loaded = load_from_arguments(args)
    params, settings = loaded.params, loaded.settings
    out = make_folder(Path(args.out))
    preset = cracking_pressure(params)
    held = args.protocol == 'held-preset'
    print(
        f'parameter study: {len(study_cases())} runs; protocol '
        f'{args.protocol}: {PROTOCOLS[args.protocol]}'
        + (f'; preset {preset / 1e6:.4f} MPa' if held else ''),
        file=sys.stderr,
    )
    backend = open_backend('study', args.scheduler, args.workers, args.dashboard, True)
    try:
        results = run_all(
            params,
            settings['step_size'],
            backend,
            out / 'results.jsonl',
            args.protocol,
            preset,
            args.resume,
        )
    finally:
        backend.close()
    write_sensitivity(out / 'sensitivity.csv', results)
    write_table3(out / 'table3.csv', results)
    write_figures(out, results, args.protocol)
    for label, result in results.items():
        reasons = result['measures']['reasons']
        if len(reasons) == len(MEASURE_NAMES) and len(set(reasons.values())) == 1:
            reasons = {'all measures': next(iter(reasons.values()))}
        for name, reason in reasons.items():
            print(f'note: {label}: {name}: {reason}', file=sys.stderr)
        if 'note' in result['measures']['details']:
            print(f'note: {label}: {result["measures"]["details"]["note"]}', file=sys.stderr)
    print(
        f'wrote {out}/sensitivity.csv, {out}/table3.csv and Figures 6-13 as PNG '
        f'(protocol {args.protocol})'
    )
    return 0
