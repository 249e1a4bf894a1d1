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
Figures: the paper's Figure 5 (step response) and the parameter-study plots.

Matplotlib with the Agg backend: files only, no display needed.
"""

from pathlib import Path

import matplotlib


matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402  (backend first)
import numpy as np  # noqa: E402
from valve_sim.analysis.steps.measures import ENVELOPE_DECAY, MEASURE_NAMES  # noqa: E402
from valve_sim.core.output_files import replacing  # noqa: E402


MEASURE_LABELS = {
    'P_o_percent': 'P_o, pressure increment [%]',
    'P_1_percent': 'P_1, pressure overshoot [%]',
    'T_1_ms': 'T_1, peak rising time [ms]',
    'r_d': 'r_d, damping ratio [-]',
    'T_d_ms': 'T_d, period of damped vibration [ms]',
    'T_s_ms': 'T_s, settling time [ms]',
}


def save_figure(figure, path, dpi):
    """
    Write figure to path (its format from the suffix, PNG without one) and close it.

    Written whole through a temporary file (core.output_files.replacing): a link at
    path is replaced, never followed; an existing folder at path is an error.
    """
    path = Path(path)
    try:
        with replacing(path, 'wb') as stream:
            figure.savefig(stream, dpi=dpi, format=path.suffix[1:].lower() or 'png')
    finally:
        plt.close(figure)


def _measure_text(measures):
    lines = []
    for name in MEASURE_NAMES:
        value = measures.get(name)
        lines.append(f'{name} = {value:.4g}' if value is not None else f'{name}: none')
    return '\n'.join(lines)


def _text_box(axis, corner, text, opacity):
    """Write monospace text in a white box whose lower right corner is at corner (axis units)."""
    axis.text(
        *corner,
        text,
        transform=axis.transAxes,
        ha='right',
        va='bottom',
        fontsize=8,
        family='monospace',
        bbox={'facecolor': 'white', 'alpha': opacity, 'edgecolor': '0.8'},
    )


def plot_step_response(
    path,
    time,
    supply_pressure,
    main_valve_displacement,
    poppet_displacement,
    t_step,
    measures=None,
    title='Step response (paper Figure 5)',
    flows=None,
    pressure='p_s',
):
    """
    Figure 5: p_s, x and y against time, each divided by its value at the step; writes a PNG.

    time [s], pressures [Pa], displacements [m]; t_step [s]; measures: the dict of
    StepMeasures.as_dict() to print beside the curves (optional). A signal that is
    zero (or undefined) at the step, as from a closed valve, cannot be divided by
    it: its panel shows it in MPa or mm instead, and says why. flows: {label: flow
    [m^3/s]} drawn in L/min in a fourth panel (the inlet and the relief flow);
    pressure: the name of the pressure drawn ('p_s - p_t' above a tank).
    """
    time = np.asarray(time, dtype=float)
    before = int(np.searchsorted(time, t_step, side='right')) - 1
    before = max(before, 0)
    panels = 3 + bool(flows)
    figure, axes = plt.subplots(
        panels, 1, sharex=True, figsize=(8, 8 + 2 * (panels - 3)), constrained_layout=True
    )
    shown = f'({pressure})' if ' ' in pressure else pressure
    curves = (
        (
            supply_pressure, f'P = {shown} / {shown}(t_step) [-]', f'{pressure} [MPa]', 1e-6,
            'tab:blue',
        ),
        (main_valve_displacement, 'X = x / x(t_step) [-]', 'x [mm]', 1e3, 'tab:red'),
        (poppet_displacement, 'Y = y / y(t_step) [-]', 'y [mm]', 1e3, 'tab:green'),
    )
    for axis, (signal, ratio_label, unit_label, scale, colour) in zip(axes, curves):
        signal = np.asarray(signal, dtype=float)
        at_step = signal[before] if signal.size else 0.0
        if at_step != 0.0 and np.isfinite(at_step):
            values, label = signal / at_step, ratio_label
        else:
            values, label = signal * scale, f'{unit_label}\n({at_step:g} at the step)'
        axis.plot(time, values, color=colour, linewidth=0.9)
        axis.axvline(t_step, color='0.6', linestyle=':', linewidth=0.8)
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
    for (name, flow), colour in zip((flows or {}).items(), ('0.4', 'tab:purple', 'tab:orange')):
        axes[3].plot(time, np.asarray(flow) * 6e4, color=colour, linewidth=0.9, label=name)
    if flows:
        axes[3].axvline(t_step, color='0.6', linestyle=':', linewidth=0.8)
        axes[3].set_ylabel('flow [L/min]')
        axes[3].grid(True, alpha=0.3)
        axes[3].legend(loc='lower right')
    axes[-1].set_xlabel('time [s]')
    axes[0].set_title(title)
    if measures:
        _text_box(axes[0], (0.99, 0.05), _measure_text(measures), opacity=0.8)
    save_figure(figure, path, dpi=120)


def plot_sensitivity(path, symbol, series, title):
    """
    Figures 6, 7, 9-12: the six measures against the variation of one parameter.

    series: {variation_percent: measures dict}; undefined measures are named on the plot
    (their reasons are in the measures' "reasons").
    """
    figure, axes = plt.subplots(2, 3, figsize=(11, 6), constrained_layout=True)
    percents = sorted(series)
    _envelope_beside_settling_time(axes.flat[MEASURE_NAMES.index('T_s_ms')], series, percents)
    for axis, name in zip(axes.flat, MEASURE_NAMES):
        points = [(p, series[p][name]) for p in percents if series[p][name] is not None]
        if points:
            axis.plot(*zip(*points), 'o-', color='tab:blue')
        missing = [p for p in percents if series[p][name] is None]
        if missing:
            axis.text(
                0.02,
                0.02,
                'undefined at ' + ', '.join(f'{p:+d} %' for p in missing),
                transform=axis.transAxes,
                fontsize=8,
                color='tab:red',
            )
        axis.set_title(MEASURE_LABELS[name], fontsize=9)
        axis.set_xlabel(f'variation of {symbol} [%]')
        axis.grid(True, alpha=0.3)
    figure.suptitle(f'{title}: effect of {symbol}')
    save_figure(figure, path, dpi=110)


def _envelope_beside_settling_time(axis, series, percents):
    """On T_s's panel, its continuous companion: the envelope's decay rate, right axis."""
    points = [(p, series[p].get(ENVELOPE_DECAY)) for p in percents]
    points = [(p, value) for p, value in points if value is not None]
    if not points:
        return
    twin = axis.twinx()
    twin.plot(*zip(*points), 's--', color='tab:orange', markersize=4)
    twin.set_ylabel('envelope decay rate [1/s]', color='tab:orange', fontsize=8)
    twin.tick_params(axis='y', colors='tab:orange', labelsize=8)


def plot_poppet_waveforms(path, waveforms, t_step):
    """
    Figure 8: pilot poppet displacement y against time for the m_p variations.

    waveforms: {variation_percent: (time [s], y [m])}.
    """
    figure, axis = plt.subplots(figsize=(8, 4.5), constrained_layout=True)
    for percent in sorted(waveforms):
        time, y = waveforms[percent]
        window = (time >= t_step - 0.01) & (time <= t_step + 0.1)
        axis.plot(
            (time[window] - t_step) * 1e3,
            y[window] * 1e6,
            linewidth=0.9,
            label=f'm_p {percent:+d} %',
        )
    axis.set_xlabel('time after the step [ms]')
    axis.set_ylabel('poppet displacement y [µm]')
    axis.set_title('Figure 8: pilot poppet displacement for the m_p variations')
    axis.grid(True, alpha=0.3)
    axis.legend()
    save_figure(figure, path, dpi=110)


def plot_pressure_increment(path, series):
    """Figure 13: P_o against the variations of d_c and k_p. series: {symbol: {percent: P_o}}."""
    figure, axis = plt.subplots(figsize=(6, 4.5), constrained_layout=True)
    for symbol, values in series.items():
        points = [(p, v) for p, v in sorted(values.items()) if v is not None]
        axis.plot(*zip(*points), 'o-', label=symbol)
    axis.set_xlabel('variation [%]')
    axis.set_ylabel(MEASURE_LABELS['P_o_percent'])
    axis.set_title('Figure 13: pressure increment against d_c and k_p')
    axis.grid(True, alpha=0.3)
    axis.legend()
    save_figure(figure, path, dpi=110)


def plot_measures_fit(path, target, measures, waveforms):
    """
    Calibration to measures: the model's step response, and each measure against its target.

    target: calibration.targets.MeasuresTarget; measures: StepMeasures.as_dict() of the
    calibrated model; waveforms: its simulation.Waveforms.
    """
    figure, (response, bars) = plt.subplots(
        2, 1, figsize=(8, 8), constrained_layout=True, gridspec_kw={'height_ratios': [3, 2]}
    )
    t_step = target.flow_step.step_time
    pressure = waveforms['supply_pressure']
    before = max(int(np.searchsorted(waveforms.time, t_step, side='right')) - 1, 0)
    response.plot(waveforms.time, pressure / pressure[before], color='tab:blue', linewidth=0.9)
    response.set_xlabel('time [s]')
    response.set_ylabel('P = p_s / p_s(t_step) [-]')
    response.set_title("Calibrated model: step response of the paper's test")
    response.grid(True, alpha=0.3)
    names = target.names
    offsets = [
        (measures[name] - target.values[name]) / target.tolerances[name]
        if measures[name] is not None
        else np.nan
        for name in names
    ]
    bars.bar(range(len(names)), offsets, color='tab:blue')
    bars.axhspan(-1.0, 1.0, color='tab:green', alpha=0.15, label='within tolerance')
    bars.axhline(0.0, color='0.3', linewidth=0.8)
    bars.set_xticks(range(len(names)))
    bars.set_xticklabels(
        [f'{name}\n{measures[name]:.4g} / {target.values[name]:.4g}'
         if measures[name] is not None else f'{name}\nundefined' for name in names],
        fontsize=8,
    )
    bars.set_ylabel('(model - target) / tolerance')
    bars.legend(fontsize=8)
    bars.grid(True, axis='y', alpha=0.3)
    save_figure(figure, path, dpi=110)


def plot_recording_fit(path, target, states):
    """
    Calibration to a recording: recorded and model supply pressure (and x), and the residual.

    target: calibration.targets.RecordingTarget; states: model states at its sample times.
    The recorded samples are drawn as dots above the model's line, so that both show
    where they agree; the first panel is zoomed on the first step (its first 0.2 s),
    where the dynamics are.
    """
    rows = 4 if target.position is not None else 3
    figure, axes = plt.subplots(rows, 1, figsize=(9, 2.6 * rows + 1), constrained_layout=True)
    time = target.time
    step = target.steps[0][0] if target.steps else time[0]
    near = (time >= step - 0.02) & (time <= step + 0.2)
    for axis, shown in ((axes[0], near), (axes[1], slice(None))):
        _recorded_and_model(axis, time[shown], target.pressure[shown] / 1e6,
                            states[shown, 0] / 1e6)
        axis.set_ylabel('p_s [MPa, gauge]')
    axes[0].set_title('Recording against the calibrated model: the first step, zoomed')
    axes[1].set_title('the whole recording', fontsize=9)
    axes[2].plot(time, (target.pressure - states[:, 0]) / 1e3, color='tab:red', linewidth=0.7)
    axes[2].set_ylabel('recorded - model [kPa]')
    if target.position is not None:
        _recorded_and_model(axes[3], time, target.position * 1e6, states[:, 4] * 1e6)
        axes[3].set_ylabel('main valve x [µm]')
    for axis in axes:
        axis.grid(True, alpha=0.3)
        axis.set_xlabel('time from the first sample [s]')
    save_figure(figure, path, dpi=110)


def _recorded_and_model(axis, time, recorded, model):
    """Draw a model line with the recorded samples as dots above it, and a legend."""
    axis.plot(time, model, color='tab:blue', linewidth=1.2, zorder=2, label='calibrated model')
    axis.plot(time, recorded, '.', color='black', markersize=2.0, alpha=0.6, zorder=3,
              label='recorded')
    axis.legend(fontsize=8)


def plot_characteristic(
    path, inlet_flow, supply_pressure, marks, steady_curve=None, steady_marks=None, title=None
):
    """
    Draw the static characteristic, p_s [MPa] against q_in [L/min], into a PNG at path.

    Top: the whole ramp (filling the supply volume included); bottom: zoomed on
    the pressures around cracking and rated flow. marks: a
    valve_sim.analysis.characteristic.Characteristic; steady_curve: (inlet flows
    [m^3/s], p_s [Pa]) of the exact steady state, drawn dashed; steady_marks: its
    cracking pressure (dict), listed beside the ramp's.
    """
    from valve_sim.analysis.characteristic import split_ramps

    q = np.asarray(inlet_flow, dtype=float) * 6e4
    p = np.asarray(supply_pressure, dtype=float) * 1e-6
    rising, falling = split_ramps(inlet_flow)
    figure, axes = plt.subplots(
        2, 1, figsize=(8, 8), constrained_layout=True, gridspec_kw={'height_ratios': [1, 2]}
    )
    for axis in axes:
        axis.plot(q[rising], p[rising], color='tab:blue', linewidth=1.0, label='rising ramp')
        axis.plot(q[falling], p[falling], color='tab:orange', linewidth=1.0, label='falling ramp')
        if steady_curve is not None:
            flows, pressure = steady_curve
            axis.plot(
                np.asarray(flows) * 6e4,
                np.asarray(pressure) * 1e-6,
                'k--',
                linewidth=0.9,
                label='exact steady state',
            )
        axis.set_ylabel('supply pressure p_s [MPa, gauge]')
        axis.grid(True, alpha=0.3)
    points = (
        ('cracking', marks.cracking_flow, marks.cracking_pressure, 'tab:red', 'o'),
        ('rated flow', marks.rated_flow, marks.rated_pressure, 'tab:green', 's'),
        ('reseat', marks.reseat_flow, marks.reseat_pressure, 'tab:purple', 'v'),
    )
    marked = []
    for label, flow, pressure, colour, marker in points:
        if flow is not None and pressure is not None:
            axes[1].plot(flow * 6e4, pressure * 1e-6, marker, color=colour, label=label)
            marked.append(pressure * 1e-6)
    lines = [f'cracking basis: {marks.basis}']
    for label, value in (
        ('cracking', marks.cracking_pressure),
        ('at rated flow', marks.rated_pressure),
        ('override', marks.override),
        ('reseat', marks.reseat_pressure),
        ('hysteresis', marks.hysteresis),
    ):
        lines.append(f'{label}: ' + (f'{value * 1e-6:.4f} MPa' if value is not None else 'none'))
    if steady_marks and steady_marks.get('cracking_pressure') is not None:
        lines.append(f'steady-state cracking: {steady_marks["cracking_pressure"] * 1e-6:.4f} MPa')
    _text_box(axes[1], (0.98, 0.04), '\n'.join(lines), opacity=0.85)
    if marked:
        low, high = min(marked), max(marked + [float(np.max(p))])
        margin = max(high - low, 1e-4)
        axes[1].set_ylim(low - 1.5 * margin, high + 0.5 * margin)
    axes[1].set_xlabel('inlet flow q_in [L/min]')
    axes[0].set_title(title or 'Static pressure-flow characteristic (slow ramp up and down)')
    axes[0].legend(loc='lower right', fontsize=8)
    axes[1].legend(loc='upper left', fontsize=8)
    save_figure(figure, path, dpi=120)
