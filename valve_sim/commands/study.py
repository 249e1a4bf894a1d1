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

PROTOCOL (--protocol; valve_sim.analysis.study_cases.PROTOCOLS): how the preset is
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

import numpy as np
from valve_sim.analysis.measures import ENVELOPE_DECAY, MEASURE_NAMES
from valve_sim.analysis.paper import REFERENCE_SCENARIO, STUDY_PARAMETERS, STUDY_VARIATIONS
from valve_sim.analysis.study_cases import (
    DEFAULT_PROTOCOL,
    protocol_preset,
    PROTOCOLS,
    study_cases,
)
from valve_sim.commands.cli import make_folder
from valve_sim.commands.options import add_options, load_from_arguments
from valve_sim.commands.study_backend import (
    add_protocol_arguments,
    add_runner_arguments,
    open_backend,
)
from valve_sim.core.output_files import replacing
from valve_sim.core.parameters import scaled

# The model's modules (numba, scipy) are imported in the functions that run it, so that
# `valve-sim study --help` stays quick.


FIGURE_NUMBERS = {'m_m': 6, 'm_p': 7, 'V_p': 9, 'V_c': 10, 'd_c': 11, 'k_p': 12}
FIGURE8_PARAMETER = 'm_p'  # Figure 8: the poppet waveforms of the m_p variations
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


def runner_case(index, params, changes, step_size, protocol, preset_pressure):
    """
    Return one case of the study as the runner takes it: params scaled by changes.

    protocol 'held-preset' has the runner re-solve the pilot spring preload so that
    the main valve cracks at preset_pressure [Pa]; 'frozen-preload' keeps it.
    """
    return {
        'index': index,
        'params': scaled(params, changes),
        'preset_pressure': protocol_preset(protocol, preset_pressure),
        'scenario': REFERENCE_SCENARIO,
        'step_size': step_size,
        'record': ['poppet_displacement'] if set(changes) <= {FIGURE8_PARAMETER} else [],
        'envelope': True,
    }


def study_result(row, protocol, preset_pressure):
    """
    Return a runner row as {'measures': ..., 'poppet': (time, y) or None, 'case': CASE_COLUMNS}.

    A case that could not run gets every measure None with the reason.
    """
    case = {
        'protocol': protocol,
        'preset_pressure_Pa': preset_pressure,
        'cracking_pressure_Pa': row.get('cracking_pressure'),
        'pilot_spring_preload_m': row.get('pilot_spring_preload'),
        'initial_supply_pressure_Pa': row.get('initial_supply_pressure'),
        'initial_main_valve_displacement_m': row.get('initial_main_valve_displacement'),
    }
    if row['error']:
        reasons = dict.fromkeys(MEASURE_NAMES, f'no step response: {row["error"]}')
        return {
            'measures': {**row['measures'], 'reasons': reasons, 'details': {}},
            'poppet': None,
            'case': case,
        }
    measures = {**row['measures'], 'reasons': dict(row['reasons']), 'details': {}}
    if case['initial_main_valve_displacement_m'] <= 0.0:
        measures['details']['note'] = (
            'main stage closed before the step: the valve relieves through the pilot alone'
        )
    waveforms = row.get('waveforms')
    poppet = (
        (np.asarray(waveforms['time']), np.asarray(waveforms['poppet_displacement']))
        if waveforms
        else None
    )
    return {'measures': measures, 'poppet': poppet, 'case': case}


def run_case(params, changes, step_size, protocol=DEFAULT_PROTOCOL, preset_pressure=None):
    """
    Run one case here; returns {'measures', 'poppet', 'case'} as study_result().

    preset_pressure [Pa] defaults to the cracking pressure of params.
    """
    from valve_sim.analysis.study_runner import evaluate_case
    from valve_sim.core.steady_state import cracking_pressure

    if preset_pressure is None:
        preset_pressure = cracking_pressure(params)
    case = runner_case(0, params, changes, step_size, protocol, preset_pressure)
    return study_result(evaluate_case(case), protocol, preset_pressure)


def summary(measures):
    """One line of the six measures, '-' where undefined."""
    return ', '.join(
        f'{name}={measures[name]:.4g}' if measures[name] is not None else f'{name}=-'
        for name in MEASURE_NAMES
    )


def run_all(
    params,
    step_size,
    backend,
    results_path,
    protocol=DEFAULT_PROTOCOL,
    preset_pressure=None,
    resume=False,
    progress_stream=sys.stderr,
):
    """
    Run every case on the backend (None: here, serially); returns {label: study_result}.

    Rows stream to results_path (resume: see run_cases); preset_pressure [Pa]
    defaults to the cracking pressure of params.
    """
    from valve_sim.analysis.study_runner import run_cases, SerialBackend
    from valve_sim.core.steady_state import cracking_pressure

    if preset_pressure is None:
        preset_pressure = cracking_pressure(params)
    labelled = study_cases()
    rows, _ = run_cases(
        [
            runner_case(index, params, changes, step_size, protocol, preset_pressure)
            for index, (_, changes) in enumerate(labelled)
        ],
        results_path,
        backend or SerialBackend(),
        resume,
        label='study',
        progress_stream=progress_stream,
    )
    return {
        label: study_result(rows[index], protocol, preset_pressure)
        for index, (label, _) in enumerate(labelled)
    }


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
        REFERENCE_SCENARIO.step_time,
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
    backend = open_backend(args, 'study', pool_fallback=True)
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
