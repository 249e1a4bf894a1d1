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
Whether a calibration explains its target, and which parameters to free if it does not.

fit_verdict(): a recording's residuals are in units of its estimated noise, so a model
that explains it leaves a residual RMS of about 1 noise level (p_s, and x where
recorded). The rule: a residual RMS more than FAR_ABOVE (3) times the noise is far
above it: the model cannot explain the recording with these free parameters (it misses
it by at least sqrt(3^2 - 1) = 2.8 noise levels RMS, beyond any estimate of the noise).
A measures target's residuals are in units of each measure's tolerance: the fit
explains it when every measure lies within its tolerance (|residual| <= 1).

freeing_suggestions(): the sensitivity of the six measures' residual (measures_residual:
a recording's measures against the model's, in the paper's tolerances) to each model
parameter that was not fitted (a central difference at the fit: two runs each, and
two for each fitted one), projected off what the fitted parameters can already change;
the square of its projection on the residual is how much freeing that parameter would
lower the sum of squares, to first order. The parameters are listed by that
reduction, the largest first, with the residual RMS predicted if each were freed alone.
"""

import math
import time

import numpy as np
from valve_sim.analysis.calibration.parameters import apply_values, FitParameter
from valve_sim.core.errors import USER_ERRORS
from valve_sim.core.parameters import SPECS


FAR_ABOVE = 3.0  # a residual RMS above this many noise levels: not explained
SENSITIVITY_STEP = 0.01  # relative change of a parameter for its central difference
# Model parameters that are not candidates: limits of the bench and the orifice law's
# numerical transition, and the bearing coefficients (derived from the bearing inputs).
NOT_CANDIDATES = (
    'max_inlet_flow', 'burst_pressure', 'supply_pressure_limit', 'orifice_transition_pressure',
    'bearing_coefficient_1', 'bearing_coefficient_2', 'bearing_coefficient_3',
)
SHOWN = 3  # suggestions named in the text and on stderr


def fit_verdict(result, target):
    """
    Return {'explains', 'figure', 'rule', 'text'} of a CalibrationResult and its target.

    figure: for a recording, the p_s residual RMS over the noise estimate (and
    'main_valve_figure' where x is recorded); for measures, the largest |residual| in
    units of its tolerance.
    """
    residuals = np.asarray(result.residuals, dtype=float)
    if target.kind == 'measures':
        figure = float(np.max(np.abs(residuals)))
        explains = figure <= 1.0
        rule = 'every measure within its tolerance (|model - target| <= tolerance)'
        text = f"the largest miss is {figure:.3g} times its measure's tolerance"
        return {'explains': explains, 'figure': figure, 'rule': rule, 'text': text}
    names = np.asarray(target.residual_names)
    verdict = {'rule': f'residual RMS at most {FAR_ABOVE:g} times the noise estimate'}
    parts = []
    for name, key, label in (('supply_pressure', 'figure', 'p_s'),
                             ('main_valve', 'main_valve_figure', 'x')):
        part = residuals[: len(names)][names == name]
        if part.size:
            verdict[key] = float(np.sqrt(np.mean(part ** 2)))
            parts.append(f'{label} residual RMS {verdict[key]:.3g} times the noise estimate')
    verdict['explains'] = all(verdict.get(key, 0.0) <= FAR_ABOVE
                              for key in ('figure', 'main_valve_figure'))
    verdict['text'] = ', '.join(parts)
    return verdict


def verdict_line(verdict, fitted_names):
    """Return the one-line verdict for the report's text and stderr."""
    if verdict['explains']:
        return f'fit explains the target: {verdict["text"]} ({verdict["rule"]})'
    return (f'the model does NOT explain the target with {", ".join(fitted_names)} free: '
            f'{verdict["text"]}, outside the rule ({verdict["rule"]})')


def judged(problem, result, progress=None):
    """Return (fit_verdict, freeing_suggestions or None) of a finished calibration."""
    verdict = fit_verdict(result, problem.target)
    if verdict['explains'] or result.interrupted:
        return verdict, None
    if progress:
        progress(verdict_line(verdict, [p.symbol for p in problem.fitted]) + ': finding the '
                 'parameters whose freeing would lower the residual most')
    return verdict, freeing_suggestions(problem, result, progress)


def verdict_lines(report):
    """Return the verdict and, where computed, the parameters to free: the report's lines."""
    fitted = [entry['symbol'] for entry in report['fitted']
              if not entry['name'].startswith('step_time_')]
    lines = [report['verdict']['line']] if 'verdict' in report else []
    return lines + (suggestion_lines(report['freeing'], fitted) if 'freeing' in report else [])


def candidates(problem):
    """Return the model parameters a fit could free: not fitted, tied, or NOT_CANDIDATES."""
    from valve_sim.core.catalogue import section_of

    taken = {p.name for p in problem.fitted} | set(problem.ties)
    return [name for name in SPECS if section_of(name) == 'model'
            and name not in taken and name not in NOT_CANDIDATES
            and problem.params.get(name)]


def measures_residual(target):
    """
    Return residual(params): the model's six measures against the target's, in tolerances.

    A measures target's own residuals; for a recording, the measures of its first step
    in the recording and in the model driven by its flow (the recording's undefined
    ones left out), each in units of the paper's tolerance (calibration.targets.
    PAPER_TOLERANCES).
    """
    from valve_sim.analysis.calibration.targets import (
        PAPER_TOLERANCES,
        UNDEFINED_MEASURE_RESIDUAL,
    )
    from valve_sim.analysis.steps.measure_windows import Cut
    from valve_sim.analysis.steps.measures import MEASURE_NAMES, step_measures
    from valve_sim.core.model import X

    if target.kind == 'measures':
        return target.residuals
    t_step = (target.step_times or [target.steps[0][0]])[0]
    direction = target.steps[0][2]
    later = [step[0] for step in target.steps if step[0] > t_step]
    cut = Cut(later[0], f'the inlet-flow step at {later[0]:.6f} s') if later else None

    def measures(pressure, position):
        return step_measures(target.time, pressure, position, t_step, direction,
                             cut=cut).values

    recorded = measures(target.pressure, target.position)
    names = [name for name in MEASURE_NAMES if recorded[name]]

    def residual(params):
        states = target.model_output(params)
        model = measures(states[:, 0], None if target.position is None else states[:, X])
        return np.array([
            (model[name] - recorded[name]) / PAPER_TOLERANCES[name]
            if model[name] is not None else UNDEFINED_MEASURE_RESIDUAL for name in names])
    residual.names = names
    return residual


def freeing_suggestions(problem, result, progress=None):
    """
    Rank the parameters not fitted by how much freeing each would lower the residual.

    The residual: the six measures' (measures_residual), smooth in the parameters where
    a recording's trace residual is not (a misfit of a few kPa is mostly a slip of the
    oscillation's phase, and a first-order prediction of it fails). Every parameter,
    fitted or not, costs two runs (a central difference of SENSITIVITY_STEP).
    Returns {'suggestions': [{'name', 'symbol', 'reduction', 'predicted_figure'}], 'runs',
    'wall_time_s', 'figure', 'skipped': {name: why}}: figure is the measures' residual RMS
    [tolerances] at the fit, predicted_figure the one predicted with that parameter freed.
    """
    began = time.monotonic()
    residual = measures_residual(problem.target)
    r = residual(result.parameters)
    runs = 1
    if not len(r):
        return {'suggestions': [], 'runs': runs, 'figure': None, 'measures': [],
                'wall_time_s': time.monotonic() - began, 'skipped': {},
                'note': "no parameter ranked: the recording's first step has none of the six "
                        'measures (docs/measures.md says why)'}
    fitted = [p for p in result.fitted if not p.name.startswith('step_time_')]
    columns, skipped = {}, {}
    names = [p.name for p in fitted] + candidates(problem)
    for k, name in enumerate(names, start=1):
        spec = SPECS[name] if name in SPECS else None
        parameter = next((p for p in fitted if p.name == name), None) or FitParameter(
            name, spec.minimum, spec.maximum, spec.unit, spec.symbol)
        value = result.values[fitted.index(parameter)] if parameter in fitted \
            else result.parameters[name]
        try:
            ends = []
            for sign in (1.0, -1.0):
                runs += 1
                ends.append(residual(apply_values(
                    result.parameters, [parameter], [value * (1.0 + sign * SENSITIVITY_STEP)],
                    problem.preset_pressure, problem.ties)))
        except USER_ERRORS as error:
            skipped[name] = str(error)
            continue
        columns[name] = (ends[0] - ends[1]) / (2.0 * SENSITIVITY_STEP)
        if progress and k % 5 == 0:
            progress(f'sensitivity of the measures: {k}/{len(names)} parameters')
    own = [columns[p.name] for p in fitted if p.name in columns]
    basis = np.linalg.qr(np.column_stack(own))[0] if own else np.zeros((len(r), 0))
    suggestions = []
    for name in candidates(problem):
        if name not in columns:
            continue
        free = columns[name] - basis @ (basis.T @ columns[name])  # what the fitted cannot do
        size = float(free @ free)
        reduction = float((r @ free) ** 2 / size) if size > 1e-12 * max(float(r @ r), 1.0) \
            else 0.0
        suggestions.append({'name': name, 'symbol': SPECS[name].symbol, 'reduction': reduction,
                            'predicted_figure': math.sqrt(max(float(r @ r) - reduction, 0.0)
                                                          / max(len(r), 1))})
    suggestions.sort(key=lambda entry: -entry['reduction'])
    return {'suggestions': suggestions, 'runs': runs, 'figure': float(np.sqrt(np.mean(r ** 2))),
            'measures': list(getattr(residual, 'names', problem.target.residual_names)),
            'wall_time_s': time.monotonic() - began, 'skipped': skipped}


def suggestion_lines(freeing, fitted_names):
    """Return the text naming the parameters to free first, and what it cost."""
    top = freeing['suggestions'][:SHOWN]
    if not top:
        return [freeing.get('note', 'no parameter left to free')]
    lines = [
        "parameters whose freeing would lower the residual most: the six measures' residual "
        f'RMS is {freeing["figure"]:.3g} tolerances at the fit (first-order prediction from '
        f'its sensitivities: {freeing["runs"]} runs, {freeing["wall_time_s"]:.1f} s):'
    ]
    for entry in top:
        lines.append(f'  {entry["name"]} ({entry["symbol"]}): predicted '
                     f'{entry["predicted_figure"]:.3g} tolerances if freed')
    lines.append('  try: --fit ' + ','.join([*fitted_names, *(e['symbol'] for e in top[:2])]))
    return lines
