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
spread over all cores.

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
  sensitivity.csv   parameter, variation_percent, protocol, preset and initial state, measures
  table3.csv        measure, table1, table2, relative_change_percent, protocol
  figure06_m_m.png ... figure12_k_p.png, figure08_pilot_poppet.png, figure13_P_o.png
A case without a step response (no steady state, no relief through the main
stage, divergence) has empty measures and its reason in the CSV.
"""

from concurrent.futures import as_completed, ProcessPoolExecutor
import csv
import os
from pathlib import Path
import sys

from valve_sim.analysis.measures import MEASURE_NAMES, step_measures
from valve_sim.analysis.paper import REFERENCE_SCENARIO, STUDY_PARAMETERS, STUDY_VARIATIONS
from valve_sim.analysis.study_cases import (
    case_parameters,
    DEFAULT_PROTOCOL,
    PROTOCOLS,
    study_cases,
)
from valve_sim.commands.simulate import add_parameter_arguments, load_from_arguments
from valve_sim.core.integrator import IntegrationError
from valve_sim.core.parameters import ParameterError
from valve_sim.core.simulation import simulate
from valve_sim.core.steady_state import cracking_pressure, SteadyStateError


FIGURE_NUMBERS = {'m_m': 6, 'm_p': 7, 'V_p': 9, 'V_c': 10, 'd_c': 11, 'k_p': 12}
POPPET_SAMPLE_INTERVAL = 1e-4  # [s] for Figure 8's waveforms
CASE_COLUMNS = (
    'protocol',
    'preset_pressure_Pa',
    'cracking_pressure_Pa',
    'pilot_spring_preload_m',
    'initial_supply_pressure_Pa',
    'initial_main_valve_displacement_m',
)


def add_arguments(parser):
    add_parameter_arguments(parser)
    parser.add_argument(
        '--out', required=True, metavar='DIR', help='output folder (created if missing)'
    )
    parser.add_argument(
        '--protocol',
        choices=PROTOCOLS,
        default=DEFAULT_PROTOCOL,
        help='held-preset: preload re-solved per case, the preset held (default, the paper); '
        'frozen-preload: the preload of the parameter file in every case',
    )
    parser.add_argument(
        '--frozen-preload',
        dest='protocol',
        action='store_const',
        const='frozen-preload',
        help='same as --protocol frozen-preload',
    )
    parser.add_argument('--step-size', type=float, metavar='S', help='RK4 step [s] (default 1e-5)')
    parser.add_argument(
        '--jobs',
        type=int,
        default=os.cpu_count() or 1,
        metavar='N',
        help='parallel processes (default: all cores)',
    )


def run_case(params, changes, step_size, protocol=DEFAULT_PROTOCOL, preset_pressure=None):
    """
    Run one case; returns {'measures': as_dict(), 'poppet': (time, y), 'case': CASE_COLUMNS}.

    preset_pressure [Pa] defaults to the cracking pressure of params. A case that
    cannot run gets every measure None with the reason; it never raises for the physics.
    """
    if preset_pressure is None:
        preset_pressure = cracking_pressure(params)
    case = dict.fromkeys(CASE_COLUMNS)
    case.update(protocol=protocol, preset_pressure_Pa=preset_pressure)
    try:
        case_params = case_parameters(params, changes, protocol, preset_pressure)
        case['pilot_spring_preload_m'] = case_params['pilot_spring_preload']
        case['cracking_pressure_Pa'] = cracking_pressure(case_params)
        waveforms = simulate(
            case_params, REFERENCE_SCENARIO, step_size, POPPET_SAMPLE_INTERVAL
        )
    except (ParameterError, SteadyStateError, IntegrationError) as error:
        reason = f'no step response: {error}'
        measures = {
            **dict.fromkeys(MEASURE_NAMES),
            'reasons': dict.fromkeys(MEASURE_NAMES, reason),
            'details': {},
        }
        return {'measures': measures, 'poppet': None, 'case': case}
    case['initial_supply_pressure_Pa'] = float(waveforms['supply_pressure'][0])
    case['initial_main_valve_displacement_m'] = float(waveforms['main_valve_displacement'][0])
    measures = step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        REFERENCE_SCENARIO.step_time,
    ).as_dict()
    if case['initial_main_valve_displacement_m'] <= 0.0:
        measures['details']['note'] = (
            'main stage closed before the step: the valve relieves through the pilot alone'
        )
    return {
        'measures': measures,
        'poppet': (waveforms.time, waveforms['poppet_displacement']),
        'case': case,
    }


def summary(measures):
    """One line of the six measures, '-' where undefined."""
    return ', '.join(
        f'{name}={measures[name]:.4g}' if measures[name] is not None else f'{name}=-'
        for name in MEASURE_NAMES
    )


def run_all(
    params, step_size, jobs, protocol=DEFAULT_PROTOCOL, preset_pressure=None, progress=print
):
    """Run every case in parallel; returns {label: run_case result}."""
    if preset_pressure is None and protocol == 'held-preset':
        preset_pressure = cracking_pressure(params)
    cases = study_cases()
    results = {}
    with ProcessPoolExecutor(max_workers=max(1, jobs)) as pool:
        futures = {
            pool.submit(run_case, params, changes, step_size, protocol, preset_pressure): label
            for label, changes in cases
        }
        for done, future in enumerate(as_completed(futures), 1):
            label = futures[future]
            results[label] = future.result()
            progress(f'[{done:2d}/{len(cases)}] {label:<14} {summary(results[label]["measures"])}')
    return results


def _label(symbol, percent):
    return f'{symbol} {percent:+d} %' if percent else 'reference'


def _value(measures, name):
    return measures[name] if measures[name] is not None else ''


def write_sensitivity(path, results):
    with open(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(
            ['parameter', 'variation_percent', *CASE_COLUMNS, *MEASURE_NAMES, 'reasons']
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
                        *(_value(measures, name) for name in MEASURE_NAMES),
                        reasons,
                    ]
                )


def write_table3(path, results):
    table1, table2 = results['reference']['measures'], results['table2']['measures']
    protocol = results['reference']['case']['protocol']
    with open(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(['measure', 'table1', 'table2', 'relative_change_percent', 'protocol'])
        for name in MEASURE_NAMES:
            a, b = table1[name], table2[name]
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
    params, settings = load_from_arguments(args)
    step_size = settings['step_size']
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    preset = cracking_pressure(params)
    held = args.protocol == 'held-preset'
    print(
        f'parameter study: {len(study_cases())} runs on {args.jobs} processes; protocol '
        f'{args.protocol}: {PROTOCOLS[args.protocol]}'
        + (f'; preset {preset / 1e6:.4f} MPa' if held else ''),
        file=sys.stderr,
    )
    results = run_all(
        params,
        step_size,
        args.jobs,
        args.protocol,
        preset,
        progress=lambda line: print(line, file=sys.stderr, flush=True),
    )
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
