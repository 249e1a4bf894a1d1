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
The paper's six step-response measures, as docs/measures.md defines them.

This is the only implementation: the command line, the live analyser and bag
analysis all call step_measures(), at steps found and dated by step_detection.

Inputs are sampled waveforms: time t [s], supply pressure p_s [Pa, gauge],
main-valve displacement x [m], and t_step [s], the time at which the inlet-flow
step took effect in the model (the last sample computed with the old flow).

Settling time T_s: the paper's, from x (the time after which x stays within
x_inf +- 5 % of the step width), wherever x is recorded. A rig rarely records x;
without it (x None or NaN in the window) T_s comes from the supply pressure: the
time after which |p_s - p_inf| stays below 5 % of the first overshoot p_1 - p_inf.
(5 % of the pressure step P_o would be a band of a few kPa, smaller than the
ripple of any real pressure signal.) details['T_s_from'] says which one was used.

How overshoot peaks are found (so that pilot-stage ripple is never taken for a
peak): the deviation e = direction * (p_s - p_inf) is split into lobes with a
hysteresis band of PEAK_BAND times the largest deviation in the window. A lobe
starts when e rises above +band and ends when e falls below -band; the k-th
overshoot is the extreme of the k-th lobe (a lobe must begin with a rise).
Ripple much smaller than the band cannot start or end a lobe. The extreme's
time and value are refined by a least-squares parabola through the lobe
samples within PEAK_FIT_DEPTH of the extreme, which makes the result nearly
independent of the sample rate (1 kHz from the node, 10 kHz offline).

A companion to T_s, not one of the six: envelope_decay_rate(), the decay rate of
the oscillation's envelope, fitted to all its swings. T_s moves in steps of about
half a period (a swing just inside or just outside the band); the decay rate moves
continuously with the parameters (docs/measures.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, TYPE_CHECKING

import numpy as np
from valve_sim.analysis.steps.measure_windows import (  # noqa: F401 (the measures' constants)
    at_rest, Cut, early_end, FINAL_VALUE_MEASURES, MEASURE_NAMES, SETTLED_SPAN, SETTLING_BAND,
    WINDOW,
)
from valve_sim.analysis.steps.sample_window import (
    between, last_at_or_before, last_span, window_end,
)

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


ENVELOPE_DECAY = 'envelope_decay_per_s'  # T_s's continuous companion (docs/measures.md)
PEAK_BAND = 0.1  # lobe hysteresis, fraction of the largest deviation
PEAK_FIT_DEPTH = 0.2  # parabola fit over samples within 20 % of the lobe's extreme
NOT_FINITE = 'not finite: the samples in the window include inf or NaN values'


@dataclass
class StepMeasures:
    """The six measures of one step; a value of None comes with its reason."""

    values: dict[str, float | None]
    reasons: dict[str, str] = field(default_factory=dict)
    details: dict = field(default_factory=dict)

    def __post_init__(self):
        """Make a measure that is not finite (inf or NaN samples) None, with its reason."""
        for name, value in self.values.items():
            if value is not None and not math.isfinite(value):
                self.values[name] = None
                self.reasons[name] = NOT_FINITE
            elif value is not None:
                self.values[name] = float(value)  # a plain float, never an np.float64
        self.details = {
            key: None if isinstance(value, float) and not math.isfinite(value) else value
            for key, value in self.details.items()
        }

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready: the six names (None where undefined), 'reasons' and 'details'."""
        return {
            **{name: self.values.get(name) for name in MEASURE_NAMES},
            'reasons': dict(self.reasons),
            'details': dict(self.details),
        }


def _refined_extreme(t, e, start, stop):
    """(time, deviation) of the extreme of e[start:stop], refined by a parabola fit."""
    i = start + int(np.argmax(e[start:stop]))
    peak = e[i]
    near = np.arange(start, stop)[e[start:stop] >= peak - PEAK_FIT_DEPTH * abs(peak)]
    if len(near) < 3:
        near = np.arange(max(i - 1, start), min(i + 2, stop))
    if len(near) >= 3:
        tc = t[near] - t[i]
        a, b, c = np.polyfit(tc, e[near], 2)
        if a < 0.0:
            vertex = -b / (2.0 * a)
            if tc[0] <= vertex <= tc[-1]:
                return t[i] + vertex, c - b * b / (4.0 * a)
    return t[i], peak


def _lobes(e, band):
    """
    (start, stop) index ranges where e stays above -band after rising above +band.

    Only a rise counts: samples that start above +band (a response that begins
    above its settled value) open no lobe until e has been below +band once.
    A hysteresis switch, computed on whole arrays: after the first sample at or
    below +band, a sample above +band switches it on (a lobe starts) and one
    below -band switches it off (the lobe ends there); other samples leave it.
    """
    e = np.asarray(e)
    armed = np.flatnonzero(e <= band)
    if len(armed) == 0:
        return []
    events = np.zeros(len(e), dtype=np.int8)
    events[e > band] = 1
    events[e < -band] = -1
    events[: armed[0] + 1] = 0
    where = np.flatnonzero(events)
    kinds = events[where]
    switched = kinds != np.concatenate([[-1], kinds[:-1]])
    starts, stops = where[switched & (kinds == 1)], where[switched & (kinds == -1)]
    lobes = [(int(start), int(stop)) for start, stop in zip(starts, stops)]
    if len(starts) > len(stops):
        lobes.append((int(starts[-1]), len(e)))
    return lobes


def _settling_time(t, x, x_0, x_inf, t_step, width=None, signal='the main valve'):
    """
    Return the time [s] after t_step from which x stays within x_inf +- 5 % of width.

    width defaults to the step width |x_inf - x_0|. Returns (time, None), or
    (None, a reason) when there is no such time.
    """
    width = abs(x_inf - x_0) if width is None else width
    if width == 0.0:
        if x_0 == 0.0:
            return None, (
                'no relief through the main stage: the main valve stayed on its seat '
                '(the pilot alone passes this flow)'
            )
        return None, 'the main valve did not move (zero step width)'
    outside = np.flatnonzero(np.abs(x - x_inf) > SETTLING_BAND * width)
    if len(outside) == 0:
        return 0.0, None
    last = outside[-1]
    if last >= len(x) - 1 or last_span(t[last], t[-1], SETTLED_SPAN):
        return (
            None,
            f'{signal} does not settle inside the window '
            '(still outside the band in its last 50 ms)',
        )
    # Interpolate the final entry into the band between samples last and last + 1.
    bound = x_inf + math.copysign(SETTLING_BAND * width, x[last] - x_inf)
    fraction = (x[last] - bound) / (x[last] - x[last + 1])
    entry = t[last] + fraction * (t[last + 1] - t[last])
    # A later swing whose samples stay inside but whose peak leaves the band between
    # samples (seen at 1 kHz, not at 10 kHz) is an exit too: refine each later local
    # extreme by the parabola through it and its neighbours, as the overshoot peaks.
    # A swing far inside cannot leave: the parabola through a local extreme d_1 and its
    # neighbours d_0, d_2 (about evenly spaced) peaks at most (2 d_1 - d_0 - d_2) / 8
    # above d_1, so only the extremes with d_1 + (2 d_1 - d_0 - d_2) >= band / 2 are fitted.
    deviation = np.abs(x - x_inf)
    band = SETTLING_BAND * width
    later = np.arange(last + 2, len(x) - 1)
    before, here, after = deviation[later - 1], deviation[later], deviation[later + 1]
    reach = here + (2.0 * here - before - after)
    for j in later[(here >= before) & (here >= after) & (reach >= 0.5 * band)]:
        exit_time = _parabola_exit(t[j - 1:j + 2], deviation[j - 1:j + 2], band)
        if exit_time is not None:
            entry = exit_time
    return entry - t_step, None


def _parabola_exit(t, deviation, band):
    """Return where the parabola through 3 samples falls back below band after its peak."""
    tc = t - t[1]
    a, b, c = np.polyfit(tc, deviation, 2)
    if a >= 0.0 or c - b * b / (4.0 * a) <= band:
        return None
    root = (-b - math.sqrt(b * b - 4.0 * a * (c - band))) / (2.0 * a)  # the later root
    return t[1] + min(root, tc[-1])


def step_measures(t: ArrayLike, supply_pressure: ArrayLike,
                  main_valve_displacement: ArrayLike | None, t_step: float, direction: int = 1,
                  window: float = WINDOW, cut: Cut | None = None, since: Cut | None = None
                  ) -> StepMeasures:
    """
    Compute the six measures of the step at t_step [s] (docs/measures.md), as StepMeasures.

    t [s], supply_pressure p_s [Pa], main_valve_displacement x [m]: equal-length
    arrays; x may be None or NaN where not recorded (T_s then from p_s). direction:
    +1 for a rising inlet flow (overshoot peaks are maxima), -1 for a falling one
    (they are minima; P_1 is then negative). window [s]: normally WINDOW. cut: the next
    change of an input (measure_windows.Cut), where the window ends if it comes first;
    since: the last change before the step (a Cut). A window that ends early (cut, or
    the recording ends) carries only the measures whose final value and peaks lie inside
    it (measure_windows.early_end); a step soon after a change has P_o only if it starts
    from rest (measure_windows.at_rest). Samples whose p_s is not finite (NaN: a tick
    that did not publish it) are left out, counted in details['pressure_samples_left_out']
    where they fall inside the window.
    """
    end = window if cut is None else min(window, max(cut.time - t_step, 0.0))
    t, supply_pressure = np.asarray(t, dtype=float), np.asarray(supply_pressure, dtype=float)
    lost, left_out = ~np.isfinite(supply_pressure), 0  # NaN: a tick without p_s, no sample
    if lost.any() and len(t) == len(lost):
        left_out = int(np.count_nonzero(lost & between(t, t_step, t_step + end)))
        t, supply_pressure = t[~lost], supply_pressure[~lost]
        if main_valve_displacement is not None and len(main_valve_displacement) == len(lost):
            main_valve_displacement = np.asarray(main_valve_displacement, dtype=float)[~lost]
    measures = _step_measures(t, supply_pressure, main_valve_displacement, t_step, direction,
                              end)
    if left_out:
        measures.details['pressure_samples_left_out'] = left_out
    lobes_closed = measures.details.pop('lobes_closed', 0)
    if cut is not None and 'p_inf' not in measures.details and end < window:
        reason = f'the window is cut to {end:.3f} s by {cut.what}'
        measures.reasons.update({name: f'{reason}: {measures.reasons.get(name, "")}'.rstrip(': ')
                                 for name in MEASURE_NAMES})
        measures.details.update(window_cut={'time': cut.time, 'by': cut.what})
        return measures
    early_end(measures, t, supply_pressure, main_valve_displacement, window, cut, lobes_closed)
    return at_rest(measures, t, supply_pressure, since)


def _step_measures(t, supply_pressure, main_valve_displacement, t_step, direction, window):
    """Compute step_measures() with p_inf from whatever window there is."""
    t = np.asarray(t, dtype=float)
    p = np.asarray(supply_pressure, dtype=float)
    x = np.full_like(t, np.nan) if main_valve_displacement is None else np.asarray(
        main_valve_displacement, dtype=float
    )
    values, reasons = dict.fromkeys(MEASURE_NAMES), {}
    if not (len(t) == len(p) == len(x)) or len(t) < 3:
        reasons.update(dict.fromkeys(MEASURE_NAMES, 'fewer than 3 samples'))
        return StepMeasures(values, reasons)
    if not (t[0] <= t_step < t[-1]):
        reasons.update(
            dict.fromkeys(
                MEASURE_NAMES,
                f'step time {t_step:.6f} s ({t_step - t[0]:+.4f} s from the first sample) '
                f'outside the samples ({t[-1] - t[0]:.4f} s long)',
            )
        )
        return StepMeasures(values, reasons)
    end, full = window_end(t, t_step, window)
    # The state before the step acts: the last sample at or before t_step (a step located
    # between samples has not moved the one before it; interpolating would mix in the
    # rise). The window starts with it, so that the response begins at its first sample.
    before = last_at_or_before(t, t_step)
    inside = between(t, t[before], end)
    tw, pw, xw = t[inside], p[inside], x[inside]
    settled = last_span(tw, end, SETTLED_SPAN)
    if not settled.any():  # a gap in the recording over the window's end: no p_inf
        reasons.update(
            dict.fromkeys(
                MEASURE_NAMES,
                f'no sample in the last {SETTLED_SPAN * 1e3:g} ms of the window '
                '(a gap in the recording), so the settled values are undefined',
            )
        )
        return StepMeasures(values, reasons)
    x_recorded = bool(np.all(np.isfinite(xw))) and np.isfinite(x[before])
    p_0 = float(p[before])
    p_inf = float(np.mean(pw[settled]))
    window_s = window if full else end - t_step
    details = {'t_step': t_step, 'window_s': window_s, 'p_0': p_0, 'p_inf': p_inf}
    if x_recorded:
        x_0, x_inf = float(x[before]), float(np.mean(xw[settled]))
        details.update(x_0=x_0, x_inf=x_inf)
    details.update(
        direction=direction, T_s_from='main_valve' if x_recorded else 'supply_pressure'
    )
    if not full:
        details['note'] = f'window truncated to {window_s:.3f} s of the {window:.3f} s defined'
    if p_0 == 0.0:
        reasons.update(
            dict.fromkeys(
                MEASURE_NAMES,
                'no step response: the valve was empty and closed before the step '
                '(supply pressure zero), so there is no relieving state to measure from',
            )
        )
        return StepMeasures(values, reasons, details)

    values['P_o_percent'] = (p_inf - p_0) / p_0 * 100.0
    if x_recorded:
        _set_settling_time(values, reasons, _settling_time(tw, xw, x_0, x_inf, t_step))

    e = direction * (pw - p_inf)
    largest = float(np.max(e))
    lobes = _lobes(e, PEAK_BAND * largest) if largest > 0.0 else []
    # An extreme on the window's last sample is a pressure still moving, not a peak.
    lobes = [
        (start, stop)
        for start, stop in lobes
        if start + int(np.argmax(e[start:stop])) < len(e) - 1
    ]
    if not lobes:
        reasons.update(
            dict.fromkeys(
                ('P_1_percent', 'T_1_ms', 'r_d', 'T_d_ms'),
                'no overshoot peak inside the window '
                '(the pressure never swings above its settled value)',
            )
        )
        if not x_recorded:
            reasons['T_s_ms'] = (
                'main valve not recorded, and the pressure-based settling time needs '
                'a first overshoot for its band'
            )
        return StepMeasures(values, reasons, details)
    details['lobes_closed'] = sum(stop < len(e) for _, stop in lobes[:2])
    t_1, e_1 = _refined_extreme(tw, e, *lobes[0])
    if not x_recorded:
        _set_settling_time(
            values,
            reasons,
            _settling_time(tw, pw, p_0, p_inf, t_step, e_1, 'the supply pressure'),
        )
    values['P_1_percent'] = direction * e_1 / p_0 * 100.0
    values['T_1_ms'] = (t_1 - t_step) * 1e3
    details.update(t_1=t_1, p_1=p_inf + direction * e_1)
    if len(lobes) < 2:
        reasons.update(
            dict.fromkeys(
                ('r_d', 'T_d_ms'),
                'no second overshoot '
                '(the response does not swing back above the settled value)',
            )
        )
        return StepMeasures(values, reasons, details)
    t_2, e_2 = _refined_extreme(tw, e, *lobes[1])
    values['r_d'] = e_2 / e_1
    values['T_d_ms'] = (t_2 - t_1) * 1e3
    details.update(t_2=t_2, p_2=p_inf + direction * e_2)
    return StepMeasures(values, reasons, details)


def envelope_decay_rate(t, supply_pressure, main_valve_displacement, t_step, window=WINDOW):
    """
    Return (sigma [1/s], None) or (None, reason): the decay rate of the oscillation's envelope.

    The signal is the one T_s is taken from: x where recorded in the window, else p_s.
    Its deviation e from the settled value (the mean of the window's last 50 ms) swings
    about zero; every swing that reaches PEAK_BAND of the first overshoot is a lobe (as
    for the overshoot peaks), of either sign, and its extreme (t_k, |e_k|) is refined by
    a parabola. sigma is minus the slope of the weighted least-squares line through
    (t_k, ln |e_k|), weights |e_k| / |e_1| - PEAK_BAND: a swing that grows into the fit
    or leaves it comes in with weight zero, so sigma has no steps. For a damped
    oscillation A exp(-sigma t) cos(omega t + phi) the line is exact. Needs three swings.
    """
    t = np.asarray(t, dtype=float)
    x = None if main_valve_displacement is None else np.asarray(main_valve_displacement, float)
    end, _ = window_end(t, t_step, window)
    inside = between(t, t_step, end)
    use_x = x is not None and bool(np.all(np.isfinite(x[inside])))
    tw = t[inside]
    signal = (x if use_x else np.asarray(supply_pressure, dtype=float))[inside]
    settled = last_span(tw, end, SETTLED_SPAN)
    if len(tw) < 3 or not settled.any():
        return None, 'no settled value in the window'
    e = signal - float(np.mean(signal[settled]))
    first = float(np.max(e))
    extremes = []
    for sign in (1.0, -1.0):
        for start, stop in _lobes(sign * e, PEAK_BAND * first) if first > 0.0 else []:
            if start + int(np.argmax(sign * e[start:stop])) < len(e) - 1:
                extremes.append(_refined_extreme(tw, sign * e, start, stop))
    if len(extremes) < 3:
        return None, 'fewer than three swings of the oscillation inside the window'
    times, sizes = np.array(extremes).T
    weights = np.clip(sizes / np.max(sizes) - PEAK_BAND, 0.0, None)
    slope, _ = np.polyfit(times, np.log(sizes), 1, w=np.sqrt(weights))
    return float(-slope), None


def _set_settling_time(values, reasons, settling):
    """Store T_s [ms] of a (time [s], reason) pair, or its reason."""
    time, reason = settling
    if reason:
        reasons['T_s_ms'] = reason
    else:
        values['T_s_ms'] = time * 1e3
