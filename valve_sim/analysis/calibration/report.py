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
The outputs of a calibration (valve-sim calibrate): its parameter file, report and figure.

parameter_file_text(): calibrated.yaml, a ROS 2 parameter file of every model
parameter and setting, the fitted, tied and derived ones marked; report_document():
the report as a JSON-ready dict (fitted values, 95 % intervals, correlations,
residuals, constraints, starts, wall time); report_text(): that report for people;
plot_fit(): the recording or the target measures against the calibrated model.
Each takes a CalibrationResult of analysis.calibration.fit and its target
(analysis.calibration.targets).
"""

import math

import numpy as np
from valve_sim.analysis.calibration.parameters import BEARING_INPUTS
from valve_sim.analysis.calibration.verdict import verdict_line, verdict_lines
from valve_sim.analysis.plotting import plot_measures_fit, plot_recording_fit
from valve_sim.core.bearing import COEFFICIENTS
from valve_sim.core.parameters import NODE_NAME
from valve_sim.core.steady_state import cracking_pressure


def yaml_number(value):
    """Shortest round-trip text of a float, with a '.' in the mantissa (ROS reads a double)."""
    text = repr(float(value))
    mantissa, e, exponent = text.partition('e')
    if '.' not in mantissa:
        mantissa += '.0'
    return mantissa + (e + exponent if e else '')


def parameter_file_text(result, settings, command):
    """Return calibrated.yaml: every model parameter and setting; fitted and derived marked."""
    fitted = {p.name for p in result.fitted if p.unit != 's' or p.name in result.parameters}
    marks = dict.fromkeys(fitted, '   # fitted')
    marks.update({
        tied: f'   # = {factor:g} {source} (tied)'
        for tied, (source, factor) in result.ties.items()
    })
    if (fitted | set(result.ties)) & set(BEARING_INPUTS):
        marks.update(dict.fromkeys(COEFFICIENTS, '   # fit of the bearing (core.bearing)'))
    lines = [
        f'# Written by: {command}',
        f'# Fitted: {", ".join(sorted(fitted))}; '
        f'main-valve cracking pressure (preset_pressure) '
        f'{yaml_number(cracking_pressure(result.parameters))} Pa.',
        f"# '/**/{NODE_NAME}:' applies to valve_node in any namespace (and to valve-sim).",
        f'/**/{NODE_NAME}:',
        '  ros__parameters:',
    ]
    for name, value in result.parameters.items():
        lines.append(f'    {name}: {yaml_number(value)}{marks.get(name, "")}')
    for name, value in settings.items():
        lines.append(f'    {name}: {yaml_number(value)}')
    return '\n'.join(lines) + '\n'


def report_document(result, target, target_name, command, verdict=None, freeing=None):
    """
    Return the report as a JSON-ready dict; target_name: the measures file or the bag.

    verdict: calibration.verdict.fit_verdict's; freeing: its freeing_suggestions (or None).
    """
    fitted = []
    for k, p in enumerate(result.fitted):
        entry = {
            'name': p.name,
            'symbol': p.symbol,
            'unit': p.unit,
            'start': result.start_values[k],
            'value': result.values[k],
            'bounds': [p.lower, p.upper],
            'at_bound': bool(
                math.isclose(result.values[k], p.lower, rel_tol=1e-6)
                or math.isclose(result.values[k], p.upper, rel_tol=1e-6)
            ),
        }
        if result.intervals:
            entry['interval_95'] = list(result.intervals[k])
        fitted.append(entry)
    document = {
        'command': command,
        'target': target_name,
        'kind': target.kind,
        'fitted': fitted,
        'correlations': None
        if result.correlations is None
        else np.round(result.correlations, 4).tolist(),
        'determined_combinations': result.rank,
        'cost': result.cost,
        'constraints': result.constraints,
        'starts': result.starts,
        'evaluations': result.evaluations,
        'wall_time_s': result.wall_time,
        'interrupted': result.interrupted,
        'preset_pressure_Pa': cracking_pressure(result.parameters),
    }
    if result.uncertainty_note:
        document['uncertainty_note'] = result.uncertainty_note
    if verdict is not None:
        document['verdict'] = dict(verdict, line=verdict_line(
            verdict, [p.symbol for p in result.fitted]))
    if freeing is not None:
        document['freeing'] = freeing
    if target.kind == 'measures':
        measures, _ = target.model_output(result.parameters)
        document['measures'] = [
            {
                'name': name,
                'model': measures[name],
                'target': target.values[name],
                'tolerance': target.tolerances[name],
                'residual': float(result.residuals[k]),
            }
            for k, name in enumerate(target.names)
        ]
    else:
        count = len(target.time)
        pressure = result.residuals[:count] * target.pressure_noise
        document['recording'] = {
            'samples': count,
            'steps_at_s': [
                float(t) for t in (target.step_times or [step[0] for step in target.steps])
            ],
            'pressure_noise_estimate_Pa': target.pressure_noise,
            'pressure_residual_rms_Pa': float(np.sqrt(np.mean(pressure**2))),
            'main_valve_recorded': target.position is not None,
        }
        if target.position is not None:
            position = result.residuals[count:len(target.residual_names)] * target.position_noise
            document['recording']['main_valve_residual_rms_m'] = float(
                np.sqrt(np.mean(position**2))
            )
    return document


def report_text(report):
    """Return the report as text for people."""
    lines = [f'calibration of {report["target"]} ({report["kind"]})']
    if report['interrupted']:
        lines.append('INTERRUPTED: the best evaluation so far, no intervals')
    lines.append(f'{"parameter":<34}{"start":>13}{"fitted":>15}   95 % interval')
    for entry in report['fitted']:
        interval = entry.get('interval_95')
        shown = f'[{interval[0]:.6g}, {interval[1]:.6g}]' if interval else '-'
        bound = '  (at a bound)' if entry['at_bound'] else ''
        lines.append(
            f'{entry["name"] + " (" + entry["symbol"] + ")":<34}{entry["start"]:>13.6g}'
            f'{entry["value"]:>15.8g}   {shown} {entry["unit"]}{bound}'
        )
    if report.get('uncertainty_note'):
        lines.append(report['uncertainty_note'])
    if report['correlations'] and len(report['fitted']) > 1:
        lines.append('correlations: ' + '; '.join(
            f'{a["symbol"]}-{b["symbol"]} {report["correlations"][i][j]:+.3f}'
            for i, a in enumerate(report['fitted'])
            for j, b in enumerate(report['fitted'])
            if j > i
        ))
    if 'measures' in report:
        lines.append(
            f'{"measure":<14}{"model":>11}{"target":>11}{"tolerance":>11}{"residual":>10}'
        )
        for m in report['measures']:
            model = f'{m["model"]:11.4g}' if m['model'] is not None else f'{"-":>11}'
            lines.append(
                f'{m["name"]:<14}{model}{m["target"]:>11.4g}{m["tolerance"]:>11.4g}'
                f'{m["residual"]:>10.3f}'
            )
    else:
        r = report['recording']
        lines.append(
            f'recording: {r["samples"]} samples, steps {r["steps_at_s"]} s after the first; '
            'p_s residual '
            f'RMS {r["pressure_residual_rms_Pa"]:.4g} Pa (noise estimate '
            f'{r["pressure_noise_estimate_Pa"]:.4g} Pa); main valve '
            + ('recorded' if r['main_valve_recorded'] else 'not recorded')
        )
    lines += verdict_lines(report)
    for status in report['constraints']:
        lines.append(
            f'{"met" if status["satisfied"] else "NOT MET"}: {status["constraint"]}: '
            f'{status["value"]}'
        )
    for k, start in enumerate(report['starts'], start=1):
        lines.append(f'start {k}: cost {start["cost"]:.6g} ({start["message"]})')
    lines.append(
        f'preset (cracking) pressure {report["preset_pressure_Pa"] / 1e6:.6f} MPa; cost '
        f'{report["cost"]:.6g}; {report["evaluations"]} evaluations; wall time '
        f'{report["wall_time_s"]:.1f} s'
    )
    return '\n'.join(lines) + '\n'


def plot_fit(path, result, target):
    """Draw the target (a recording, or the measures) against the calibrated model to path."""
    if target.kind == 'measures':
        measures, waveforms = target.model_output(result.parameters)
        plot_measures_fit(path, target, measures, waveforms)
    else:
        states = target.model_output(result.parameters)
        plot_recording_fit(path, target, states)
