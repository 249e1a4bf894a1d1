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
What a robust optimisation writes: the Pareto set (CSV, JSON) and a parameter file per design.

The outcome is analysis.design.optimisation.outcome_of's: the Pareto designs with their
search and confirmation rows (analysis.design.robust_yield), the baselines (the reference
valve and Table 2) and the chosen design. A parameter file holds every model
parameter of its design under '/**/relief_valve', so it applies to a valve_node in
any namespace and to `valve-sim ... --params FILE`; under the held preset it also
holds preset_pressure, which sets the pilot spring preload when the file is loaded.
"""

from collections import Counter
import csv

from valve_sim.analysis.design.sequential_yield import planned_runs_of, runs_of
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.core.output_files import json_text, make_folder, replacing, write_text
from valve_sim.core.parameters import NODE_NAME, PARAMETERS


def parameter_file_text(problem, design, title):
    """Return the ROS 2 parameter file of a design: every parameter, the preset, the step."""
    values = {**problem.params, **design}
    lines = [
        f'# {title}',
        '# Every model parameter of the design (SI units; designed ones marked). Use:',
        '#   valve_node --ros-args --params-file THIS.yaml   (a node in any namespace)',
        '#   valve-sim simulate --params THIS.yaml',
    ]
    if problem.preset_pressure is not None:
        lines.append('# preset_pressure sets pilot_spring_preload when the file is loaded '
                     '(the adjusting screw).')
    lines += [f'/**/{NODE_NAME}:', '  ros__parameters:']
    for spec in PARAMETERS:
        note = f'  # {spec.symbol} [{spec.unit}]' + (', designed' if spec.name in design else '')
        lines.append(f'    {spec.name}: {float(values[spec.name])!r}{note}')
    if problem.preset_pressure is not None:
        lines.append(f'    preset_pressure: {float(problem.preset_pressure)!r}  # [Pa]')
    lines.append(f'    step_size: {float(problem.step_size)!r}  # [s] RK4 step it was run with')
    return '\n'.join(lines) + '\n'


def design_name(row):
    """Return the file-name stem of a design row: pareto_<candidate index>, or its label."""
    return row['label'].replace('candidate ', 'pareto_')


def yield_entry(row):
    """Return {samples, passed, fraction, ci95} of a row, or None."""
    if row is None:
        return None
    return {'samples': row['samples'], 'passed': row['passed'], 'fraction': row['yield'],
            'ci95': row['ci95']}


def design_entry(problem, row, confirmed=None, generation=None):
    """Return a JSON-ready statement of a design: values, nominal measures, yields, failures."""
    nominal = row.get('nominal') or {}
    final = confirmed or row
    return {
        'label': row['label'],
        'generation': generation,
        'design': {name: row['design'][name] for name in sorted(row['design'])},
        'error': row['error'],
        'nominal_measures': nominal.get('measures'),
        'nominal_reasons': nominal.get('reasons'),
        'nominal_decay_rate': nominal.get('decay_rate'),
        'nominal_pilot_spring_preload': nominal.get('pilot_spring_preload'),
        'search_yield': yield_entry(row),
        'confirmed_yield': yield_entry(confirmed),
        'meets_yield': problem.feasible(final),
        'failures': final.get('failures'),
        'percentiles': final.get('percentiles'),
    }


def problem_statement(problem, population, generations):
    """Return a JSON-ready statement of the problem and the budget."""
    return {
        'design': [{**bound.describe(), 'distribution': 'bounds'} for bound in problem.design],
        'objectives': [{'measure': o.measure, 'sense': o.sense} for o in problem.objectives],
        'limits': list(problem.limits),
        'tolerances': list(problem.tolerances),
        'required_yield': problem.required_yield,
        'min_decay_rate': problem.min_decay_rate,
        'protocol': problem.protocol,
        'preset_pressure': problem.preset_pressure,
        'samples': problem.samples,
        'confirm_samples': problem.confirm_samples,
        'sampler': problem.sampler,
        'seed': problem.seed,
        'confirm_seed': problem.seed + 1,
        'population': population,
        'generations': generations,
        'optimiser': 'NSGA-II (pymoo), Latin-hypercube first generation',
        'yield_interval': 'Clopper-Pearson 95 %, samples taken as independent (conservative '
        'for quasi-random samples)',
        'step_size': problem.step_size,
        'sequential': None if problem.stop_alpha is None else {
            'alpha': problem.stop_alpha,
            'first_round': problem.first_round,
            'defer_after': problem.defer_after,
            'rule': 'rounds doubling from first_round to samples, prefixes of the one draw; '
            'at each interim look: below once the failures rule out the full sample meeting '
            'the yield, else a two-sided Clopper-Pearson interval at 1 - alpha / looks '
            '(Bonferroni): stop below or above the required yield, each wrong at most '
            'alpha / 2; a nominal valve out of spec takes no samples, nor one a promising '
            'design dominates (undecided); one undecided after defer_after valves is left '
            'open; the undecided candidates on the front run on to a verdict at the end',
        },
    }


def runs_statement(records, outcome):
    """Return the runs of each stage: the search (spent, saved, decisions), the confirmation."""
    rows = [row for _, row in records]
    spent = sum(map(runs_of, rows))
    full = sum(map(planned_runs_of, rows))
    decisions = Counter(row.get('search_decision', row.get('decision', 'full')) for row in rows)
    resolved = [row for row in rows if 'search_decision' in row]
    confirmed = [c for _, _, c in outcome['pareto'] if c] + list(outcome['baselines'].values())
    return {
        'search': {'runs': spent, 'full_sample_runs': full, 'saved': full - spent,
                   'decisions': dict(sorted(decisions.items())),
                   'resolution': {
                       'candidates': len(resolved),
                       'runs': sum(row['resolution_runs'] for row in resolved),
                       'decisions': dict(sorted(Counter(row['decision']
                                                        for row in resolved).items()))}},
        'confirmation': {'designs': len(confirmed), 'runs': sum(map(runs_of, confirmed))},
    }


def comparison(chosen, table2):
    """Return {measure: {chosen, table2, change_percent}} of two rows' nominal measures."""
    result = {}
    for name in MEASURE_NAMES:
        a, b = chosen['nominal']['measures'][name], table2['nominal']['measures'][name]
        change = None if a is None or not b else 100.0 * (a - b) / abs(b)
        result[name] = {'chosen': a, 'table2': b, 'change_percent': change}
    return result


def write_outputs(out, problem, outcome, records, population, generations):
    """
    Write pareto.csv, pareto.json and params/<design>.yaml into out; return the JSON dict.

    The baselines' parameter files are written too (params/reference.yaml, table2.yaml).
    """
    params_folder = make_folder(out / 'params')
    for old in params_folder.glob('pareto_*.yaml'):
        old.unlink()
    pareto = []
    for number, (generation, row, confirmed) in enumerate(outcome['pareto']):
        entry = design_entry(problem, row, confirmed, generation)
        entry['chosen'] = number == outcome['chosen']
        entry['parameter_file'] = f'params/{design_name(row)}.yaml'
        write_text(out / entry['parameter_file'], parameter_file_text(
            problem, row['design'], f"valve-sim optimise: {row['label']}, a Pareto design"))
        pareto.append(entry)
    baselines = {}
    for label, row in outcome['baselines'].items():
        baselines[label] = design_entry(problem, row, row)
        baselines[label]['parameter_file'] = f'params/{label}.yaml'
        write_text(out / f'params/{label}.yaml', parameter_file_text(
            problem, row['design'], f'valve-sim optimise: the baseline {label}'))
    chosen = outcome['chosen']
    summary = {
        'problem': problem_statement(problem, population, generations),
        'candidates_evaluated': len(records),
        'candidates_feasible': sum(problem.feasible(row) for _, row in records),
        'candidates_undecided': sum(problem.undecided(row) for _, row in records),
        'runs': runs_statement(records, outcome),
        'pareto': pareto,
        'baselines': baselines,
        'chosen': None if chosen is None else pareto[chosen]['label'],
    }
    if chosen is not None and 'table2' in outcome['baselines']:
        summary['chosen_against_table2'] = comparison(
            outcome['pareto'][chosen][1], outcome['baselines']['table2']
        )
    write_text(out / 'pareto.json', json_text(summary) + '\n')
    write_csv(out / 'pareto.csv', problem, pareto)
    return summary


def write_csv(path, problem, pareto):
    """Write one line per Pareto design: values, nominal measures, decay, both yields."""
    names = [bound.name for bound in problem.design]
    header = ['label', 'generation', *names, *MEASURE_NAMES, 'nominal_decay_rate',
              'search_samples', 'search_yield', 'search_ci95_low', 'search_ci95_high',
              'confirm_samples', 'yield', 'ci95_low', 'ci95_high', 'meets_yield', 'chosen',
              'parameter_file']
    with replacing(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(header)
        for entry in pareto:
            search, confirmed = entry['search_yield'], entry['confirmed_yield'] or {}
            writer.writerow([
                entry['label'], entry['generation'],
                *(repr(entry['design'][name]) for name in names),
                *('' if entry['nominal_measures'][m] is None else entry['nominal_measures'][m]
                  for m in MEASURE_NAMES),
                '' if entry['nominal_decay_rate'] is None else entry['nominal_decay_rate'],
                search['samples'], search['fraction'], *search['ci95'],
                confirmed.get('samples', ''), confirmed.get('fraction', ''),
                *confirmed.get('ci95', ['', '']),
                int(entry['meets_yield']), int(entry['chosen']), entry['parameter_file'],
            ])
