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

"""The six measures on synthetic waveforms whose answers are known in closed form."""

import math

import numpy as np
import pytest
from valve_sim.analysis.steps.measures import (
    _lobes, envelope_decay_rate, MEASURE_NAMES, step_measures,
)
from valve_sim.analysis.steps.step_detection import detect_steps, StepDetector


P0, DELTA = 7.0e6, 1.0e4  # pressure before the step, settled increment [Pa]
SIGMA, OMEGA = 6.4, 2 * math.pi / 0.025  # decay rate [1/s], damped angular frequency [rad/s]
AMPLITUDE = 2.2e5  # overshoot amplitude scale [Pa]
T_STEP = 0.25
X0, X_INF, TAU = 2e-5, 1.5e-4, 0.1  # main valve: first-order move [m], time constant [s]


def synthetic(rate=1e4, ripple=0.0, direction=1):
    """
    Synthesize a step response whose peaks and settling are known exactly.

    p = p0 + d (DELTA + A e^{-s tau} sin(w tau)), x first order.
    """
    t = np.arange(0.0, T_STEP + 1.0 + 0.5 / rate, 1.0 / rate)
    tau = np.clip(t - T_STEP, 0.0, None)
    p = P0 + direction * (
        DELTA * (tau > 0) + AMPLITUDE * np.exp(-SIGMA * tau) * np.sin(OMEGA * tau)
    )
    p = p + ripple * np.sin(2 * math.pi * 720.0 * t)
    x = X0 + (X_INF - X0) * (1.0 - np.exp(-tau / TAU))
    return t, p, x


def expected():
    """Extrema of A e^{-s t} sin(w t): at w t = atan(w/s) + k pi."""
    t1 = math.atan(OMEGA / SIGMA) / OMEGA
    e1 = AMPLITUDE * math.exp(-SIGMA * t1) * math.sin(OMEGA * t1)
    t2 = t1 + 2 * math.pi / OMEGA
    e2 = AMPLITUDE * math.exp(-SIGMA * t2) * math.sin(OMEGA * t2)
    settle = TAU * math.log(1 / 0.05)
    return {
        'P_o_percent': DELTA / P0 * 100,
        'P_1_percent': e1 / P0 * 100,
        'T_1_ms': t1 * 1e3,
        'r_d': e2 / e1,
        'T_d_ms': (t2 - t1) * 1e3,
        'T_s_ms': settle * 1e3,
    }


@pytest.mark.parametrize('rate', [1e4, 1e3])
def test_known_answers_at_10_khz_and_1_khz(rate):
    t, p, x = synthetic(rate)
    result = step_measures(t, p, x, T_STEP)
    want = expected()
    assert result.reasons == {}
    # p_inf and x_inf are 50 ms means that still hold a few Pa of ringing and of the
    # exponential tail: that, not the peak finding, sets the P_o, P_1 and T_s tolerances.
    assert result.values['T_1_ms'] == pytest.approx(want['T_1_ms'], abs=0.05)
    assert result.values['T_d_ms'] == pytest.approx(want['T_d_ms'], abs=0.05)
    assert result.values['P_1_percent'] == pytest.approx(want['P_1_percent'], rel=2e-3)
    assert result.values['r_d'] == pytest.approx(want['r_d'], abs=2e-3)
    assert result.values['P_o_percent'] == pytest.approx(want['P_o_percent'], rel=2e-3)
    assert result.values['T_s_ms'] == pytest.approx(want['T_s_ms'], abs=1e3 / rate + 0.5)


@pytest.mark.parametrize('rate', [1e4, 1e3])
def test_envelope_decay_rate_is_the_decay_of_the_swings(rate):
    t, p, _ = synthetic(rate, ripple=300.0)
    decay, reason = envelope_decay_rate(t, p, None, T_STEP)  # from p_s (no x)
    assert reason is None and decay == pytest.approx(SIGMA, rel=0.01)
    ringing_x = X_INF + 1e-5 * np.exp(-SIGMA * (t - T_STEP)) * np.cos(OMEGA * (t - T_STEP))
    decay, reason = envelope_decay_rate(t, p, np.where(t < T_STEP, X0, ringing_x), T_STEP)
    assert reason is None and decay == pytest.approx(SIGMA, rel=0.01)  # from x, where recorded


def test_settling_time_steps_by_half_periods_where_the_envelope_decay_moves_smoothly():
    """Docs/measures.md: a 1 % slower decay moves T_s by 0 or by ~T_d / 2; sigma by ~1 %."""
    t = np.arange(0.0, T_STEP + 1.0, 1e-4)
    tau = np.clip(t - T_STEP, 0.0, None)
    settling, decays = [], []
    for sigma in np.linspace(6.0, 6.6, 13):
        x = X_INF - (X_INF - X0) * np.exp(-sigma * tau) * np.cos(OMEGA * tau)
        p = P0 + DELTA * (tau > 0) + AMPLITUDE * np.exp(-sigma * tau) * np.sin(OMEGA * tau)
        settling.append(step_measures(t, p, x, T_STEP).values['T_s_ms'])
        decays.append(envelope_decay_rate(t, p, x, T_STEP)[0])
    half_period = math.pi / OMEGA * 1e3  # [ms]
    steps = np.diff(settling)
    assert np.all((np.abs(steps) < 0.1 * half_period)
                  | (np.abs(np.abs(steps) - half_period) < 0.2 * half_period))
    assert np.any(np.abs(steps) > 0.5 * half_period)  # it did step
    assert np.array(decays) == pytest.approx(np.linspace(6.0, 6.6, 13), rel=0.01)


def test_pilot_ripple_is_not_taken_for_a_peak():
    t, p, x = synthetic(1e4, ripple=3e3)  # 720 Hz, 1.4 % of the overshoot
    result = step_measures(t, p, x, T_STEP)
    want = expected()
    assert result.values['T_d_ms'] == pytest.approx(want['T_d_ms'], abs=0.3)
    assert result.values['r_d'] == pytest.approx(want['r_d'], abs=0.02)


def test_falling_step_gives_undershoot_as_negative_overshoot():
    t, p, x = synthetic(1e4, direction=-1)
    result = step_measures(t, p, x, T_STEP, direction=-1)
    want = expected()
    assert result.values['P_1_percent'] == pytest.approx(-want['P_1_percent'], rel=2e-3)
    assert result.values['P_o_percent'] == pytest.approx(-want['P_o_percent'], rel=2e-3)
    assert result.values['r_d'] == pytest.approx(want['r_d'], abs=2e-3)


def test_no_second_peak_is_an_explicit_null_with_reason():
    t = np.arange(0.0, 1.3, 1e-4)
    tau = np.clip(t - T_STEP, 0.0, None)
    # Critically damped rise with one overshoot lobe that never swings back below the settled
    # value.
    p = P0 + DELTA * (1 - np.exp(-tau / 0.01)) + 3e4 * tau / 0.02 * np.exp(1 - tau / 0.02)
    x = X0 + (X_INF - X0) * (1 - np.exp(-tau / TAU))
    result = step_measures(t, p, x, T_STEP)
    assert result.values['P_1_percent'] is not None and result.values['T_1_ms'] is not None
    assert result.values['r_d'] is None and result.values['T_d_ms'] is None
    assert 'second overshoot' in result.reasons['r_d']


def test_never_settling_main_valve_is_an_explicit_null():
    t, p, _ = synthetic()
    x = X_INF + 0.5 * (X_INF - X0) * np.sin(2 * math.pi * 40 * t)  # keeps oscillating to the end
    x[t <= T_STEP] = X0
    result = step_measures(t, p, x, T_STEP)
    assert result.values['T_s_ms'] is None
    assert 'does not settle' in result.reasons['T_s_ms']


def test_no_overshoot_and_bad_input():
    t = np.arange(0.0, 1.3, 1e-4)
    p = np.where(t > T_STEP, P0 - 1e3 * (1 - np.exp(-(t - T_STEP) / 0.01)), P0)
    result = step_measures(t, p, np.full_like(t, X0), T_STEP)
    assert all(result.values[name] is None for name in ('P_1_percent', 'T_1_ms', 'r_d', 'T_d_ms'))
    assert 'zero step width' in result.reasons['T_s_ms']
    outside = step_measures(t, p, p, 5.0)
    assert all(outside.values[name] is None for name in MEASURE_NAMES)
    assert 'outside' in outside.reasons['T_1_ms']


def test_pressure_still_rising_at_the_window_end_is_no_peak():
    t = np.arange(0.0, 1.3, 1e-4)
    p = P0 + np.clip(t - T_STEP, 0.0, None) * 1e6  # ramps up to the end: no settling, no peak
    x = np.full_like(t, X0)
    result = step_measures(t, p, x, T_STEP)
    assert result.values['T_1_ms'] is None and 'no overshoot peak' in result.reasons['T_1_ms']


def test_truncated_window_is_reported():
    t, p, x = synthetic()
    keep = t < T_STEP + 0.6
    result = step_measures(t[keep], p[keep], x[keep], T_STEP)
    assert result.details['window_s'] == pytest.approx(0.6, abs=1e-3)
    assert 'truncated' in result.details['note']


def test_a_gap_over_the_window_end_is_no_settled_value():
    """No sample in the window's last 50 ms (lag skipped there): every measure null, not NaN."""
    t, p, x = synthetic(rate=1e3)
    keep = t < T_STEP + 0.94  # and the next sample after the window's end
    result = step_measures(
        np.append(t[keep], T_STEP + 1.06),
        np.append(p[keep], P0 + DELTA),
        np.append(x[keep], X_INF),
        T_STEP,
    )
    assert all(result.values[name] is None for name in MEASURE_NAMES), result.values
    assert 'no sample in the last 50 ms of the window' in result.reasons['P_o_percent']


def test_step_detector_dates_steps_at_the_last_old_sample():
    t = np.arange(0.0, 3.0, 1e-3)
    q = np.full_like(t, 5.0)
    q[t > 1.0005] = 20.0
    q[t > 2.0005] = 5.0
    steps = detect_steps(t, q * 1.6667e-5)
    assert [(round(s[0], 4), s[2]) for s in steps] == [(1.0, 1), (2.0, -1)]


def test_step_detector_merges_a_ramp_and_ignores_noise():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 1.0, 1e-3)
    q = 8.3e-5 + np.clip((t - 0.3) / 0.04, 0, 1) * 2.5e-4 + rng.normal(0, 1e-7, t.size)
    detector = StepDetector(threshold=1e-6, merge_time=0.05)
    steps = [s for s in map(detector.update, t, q) if s]
    assert len(steps) == 1 and 0.299 <= steps[0][0] <= 0.305


def _lobes_one_sample_at_a_time(e, band):
    """Find the lobes with the loop the switch describes (the reference for _lobes)."""
    lobes, start, above, armed = [], None, False, False
    for i, value in enumerate(e):
        if not armed:
            armed = value <= band
        elif not above and value > band:
            above, start = True, i
        elif above and value < -band:
            lobes.append((start, i))
            above = False
    if above:
        lobes.append((start, len(e)))
    return lobes


def test_lobes_on_arrays_equal_the_sample_loop():
    """Random walks and small integers (values exactly at +-band) give the same lobes."""
    rng = np.random.default_rng(7)
    for trial in range(4000):
        n = int(rng.integers(0, 60))
        if trial % 2:
            e, band = rng.integers(-3, 4, size=n).astype(float), float(rng.integers(0, 3))
        else:
            e, band = rng.normal(size=n).cumsum(), abs(rng.normal())
        assert _lobes(e, band) == _lobes_one_sample_at_a_time(e, band), (e, band)


def test_a_step_down_has_a_negative_overshoot_and_the_definitions_say_so(reference):
    """P_1 keeps the sign of p_1 - p_inf: below p_inf for a step down (docs/measures.md)."""
    from pathlib import Path

    from valve_sim.core.simulation import LITRE_PER_MINUTE, FlowStep, simulate

    run = simulate(reference, FlowStep(20 * LITRE_PER_MINUTE, 5 * LITRE_PER_MINUTE, 0.1, 1.2),
                   record_interval=1e-4)
    down = step_measures(run.time, run['supply_pressure'], run['main_valve_displacement'], 0.1,
                         direction=-1)
    assert down.values['P_1_percent'] < 0.0 and down.values['P_o_percent'] < 0.0
    assert down.values['T_1_ms'] > 0.0 and down.values['r_d'] > 0.0
    docs = Path(__file__).resolve().parents[2] / 'docs' / 'measures.md'
    assert 'for a step down P_1 is negative' in ' '.join(docs.read_text().split())


def test_the_window_holds_its_edge_samples_however_their_times_were_rounded(reference):
    """
    Samples timed in ns / 1e9 (valve_node's stamps, epoch too) and k * step_size agree.

    One series gives one result over a full window, however its times were computed.
    For a step at an odd millisecond t_step + 1.0 rounds below the sample at the
    window's end: it was in one series and not in the other, P_o 2e-3 apart, and the
    window was noted truncated (test_journeys failed so when the flow took two ticks).
    """
    from valve_sim.core.simulation import FlowStep, simulate

    run = simulate(reference, FlowStep(step_time=0.051, end_time=1.1), record_interval=1e-3)
    ticks = np.arange(len(run.time), dtype=np.int64) * 1_000_000  # [ns]
    epoch_ns = 1_795_953_600_000_000_000
    series = {
        'k * step_size': (run.time, 0.051),
        'ns stamps': (ticks / 1e9, 51_000_000 / 1e9),
        'epoch ns stamps': ((epoch_ns + ticks) / 1e9, (epoch_ns + 51_000_000) / 1e9),
    }
    results = {
        name: step_measures(t, run['supply_pressure'], run['main_valve_displacement'], t_step)
        for name, (t, t_step) in series.items()
    }
    for name, result in results.items():
        assert result.details['window_s'] == 1.0 and 'note' not in result.details, name
        assert result.details['p_inf'] == results['k * step_size'].details['p_inf'], name
        for measure in MEASURE_NAMES:
            # epoch times are 0.24 us apart: the peaks' times within 1 us, their fits 1e-5
            epoch = 'epoch' in name
            tolerance = {'abs': 1e-3} if epoch and measure.endswith('_ms') else {}
            assert result.values[measure] == pytest.approx(
                results['k * step_size'].values[measure], rel=1e-5 if epoch else 1e-9,
                **tolerance,
            ), (name, measure)
