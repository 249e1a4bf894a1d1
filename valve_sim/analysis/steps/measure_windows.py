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
Where a step's window ends, and which measures a window that ends early can carry.

The rule (docs/measures.md, "Where a window ends"): a step's window ends at
measures.WINDOW after it, or earlier at the next change of any input: a flow step or
ramp, a tank-pressure change (beyond the tank signal's noise, InputChanges), a fault or
parameter event that changes a value the model uses (input_events), a Cut, or where
the recording ends. On a window that ends early a measure is reported only if everything
it depends on lies before the end:

- P_o, P_1, r_d and T_s need the settled final value p_inf (x_inf): the response must
  have settled by the end, i.e. over the window's last 50 ms x stays inside its
  settling band (+-5 % of its step width, where x is recorded and moved) and p_s within
  5 % of its largest excursion from p_inf, and p_inf (a mean over 50 ms) no longer
  drifts: it differs from the mean of the 50 ms before by at most 5 % of the pressure
  step |p_inf - p_0| (P_o is a small difference of two pressures);
- T_1 (and P_1) need the first overshoot lobe closed before the end, T_d (and r_d) the
  second too: a peak whose lobe is still open may not be its extreme.

A step that comes less than WINDOW after the previous change of an input starts from
rest only if p_s stays within 5 % of the pressure step of p_0 over the 50 ms before
it; else P_o, which needs a settled p_0, is null (at_rest).
Otherwise the measure is null, with a reason naming what ended the window. This is the
one implementation: measures.step_measures applies it, and step_analysis.StepAnalysis
(the live analyser, `valve-sim analyse`, the scenario report, the test kit) finds the
changes (InputChanges) and hands each step its Cut.
"""

from collections import deque
from dataclasses import dataclass

import numpy as np
from valve_sim.analysis.steps.sample_window import between, last_span, TIME_TOLERANCE


MEASURE_NAMES = ('P_o_percent', 'P_1_percent', 'T_1_ms', 'r_d', 'T_d_ms', 'T_s_ms')
WINDOW = 1.0  # [s] analysis window after the step (docs/measures.md)
SETTLED_SPAN = 0.05  # [s] p_inf and x_inf are means over the window's last 50 ms
SETTLING_BAND = 0.05  # settling band: +-5 % of the main-valve step width
FINAL_VALUE_MEASURES = ('P_o_percent', 'P_1_percent', 'r_d', 'T_s_ms')
FIRST_PEAK_MEASURES = ('P_1_percent', 'T_1_ms')
SECOND_PEAK_MEASURES = ('r_d', 'T_d_ms')
# A tank-pressure change that cuts a window: more than TANK_NOISE_FACTOR times the noise of
# the tank signal (step_detection.noise_level of its last TANK_NOISE_SAMPLES samples,
# re-estimated every TANK_NOISE_EVERY), and at least TANK_STEP_FLOOR [Pa]: far above
# valve_node's rounding of the applied tank pressure, far below any back-pressure step.
TANK_STEP_FLOOR = 1e3
TANK_NOISE_FACTOR = 10.0  # normal noise: one false cut in ~6e11 samples (docs/measures.md)
TANK_NOISE_SAMPLES = 1000
TANK_NOISE_EVERY = 100
TANK_NOISE_FIRST = 10  # no tank change is looked for before this many samples


@dataclass(frozen=True)
class Cut:
    """A change of an input: time [s] of the last sample it has not moved; what it was."""

    time: float
    what: str


def early_end(measures, t, supply_pressure, main_valve, window, cut=None, lobes_closed=0):
    """
    Apply the rule to a StepMeasures whose window ends before window [s]; return it.

    t [s], supply_pressure [Pa], main_valve [m] (None or NaN: not recorded): the samples
    the measures were taken on; cut: the Cut that ended the window, or None (the
    recording ended); lobes_closed: how many of the first two overshoot lobes swung back
    inside the window. details get 'final_value_settled' and, for a cut, 'window_cut'.
    """
    details, values, reasons = measures.details, measures.values, measures.reasons
    if details.get('p_inf') is None or details['window_s'] >= window - TIME_TOLERANCE:
        return measures
    window_s = details['window_s']
    if cut is not None and cut.time <= details['t_step'] + window_s + TIME_TOLERANCE:
        why = f'the window is cut to {window_s:.3f} s by {cut.what}'
        details['window_cut'] = {'time': cut.time, 'by': cut.what}
        details['note'] = f'window cut to {window_s:.3f} s of the {window:.3f} s defined ' \
                          f'by {cut.what}'
    else:
        why = f'the window is truncated to {window_s:.3f} s (the recording ends)'
    settled = settled_at_the_end(t, supply_pressure, main_valve, details)
    details['final_value_settled'] = settled
    undefined = {}
    if not settled:
        undefined.update(dict.fromkeys(FINAL_VALUE_MEASURES, (
            f'{why} and the response has not settled in its last {SETTLED_SPAN * 1e3:g} ms, '
            'so it has no final value p_inf')))
    for needed, names in ((1, FIRST_PEAK_MEASURES), (2, SECOND_PEAK_MEASURES)):
        if lobes_closed < needed:
            for name in names:
                if values.get(name) is not None:  # (no peak at all keeps its own reason)
                    undefined.setdefault(name, (
                        f'{why} before the {"first" if needed == 1 else "second"} overshoot '
                        'has swung back, so its peak is not known'))
    for name, reason in undefined.items():  # undefined anyway: the early end is why
        values[name], reasons[name] = None, reason
    return measures


def settled_at_the_end(t, supply_pressure, main_valve, details):
    """
    Whether the response has settled at the end of its window (module docstring).

    details: the measures' (t_step, window_s, p_inf, x_0 and x_inf where x is recorded).
    """
    if details['window_s'] <= 2 * SETTLED_SPAN:  # no settled span after the step at all
        return False
    t, p = np.asarray(t, dtype=float), np.asarray(supply_pressure, dtype=float)
    end = details['t_step'] + details['window_s']
    inside = between(t, details['t_step'], end)
    last = inside & last_span(t, end, SETTLED_SPAN)
    before = inside & ~last & last_span(t, end - SETTLED_SPAN, SETTLED_SPAN)
    pressure = np.abs(p[inside] - details['p_inf'])
    deviation = np.abs(p[last] - details['p_inf'])
    drift = abs(float(np.mean(p[before])) - details['p_inf']) if before.any() else np.inf
    settled = bool(np.max(deviation) <= SETTLING_BAND * np.max(pressure)
                   and drift <= SETTLING_BAND * abs(details['p_inf'] - details['p_0']))
    if 'x_inf' in details and details['x_inf'] != details['x_0']:
        width = abs(details['x_inf'] - details['x_0'])
        x = np.asarray(main_valve, dtype=float)[last]
        settled = settled and bool(np.max(np.abs(x - details['x_inf'])) <= SETTLING_BAND * width)
    return settled


def at_rest(measures, t, supply_pressure, since):
    """
    Make the measures null whose step starts before p_s came to rest after since (a Cut).

    Only a change less than WINDOW before the step counts (module docstring). At rest:
    p_s moves less than 5 % of the measure's scale in the 50 ms before the step, the
    pressure step |p_inf - p_0| for P_o, the first overshoot |p_1 - p_inf| for the
    others (the remains of the last response would shift its peaks, band and settling).
    """
    details, values, reasons = measures.details, measures.values, measures.reasons
    if since is None or details.get('p_inf') is None or since.time <= details['t_step'] - WINDOW:
        return measures
    t_step, p_0, p_inf = details['t_step'], details['p_0'], details['p_inf']
    t, p = np.asarray(t, dtype=float), np.asarray(supply_pressure, dtype=float)
    moves = float(np.max(np.abs(p[between(t, t_step - SETTLED_SPAN, t_step)] - p_0)))
    details['moves_before_step_pa'] = moves
    scales = dict.fromkeys(MEASURE_NAMES, abs(details.get('p_1', p_inf) - p_inf))
    scales['P_o_percent'] = abs(p_inf - p_0)
    for name, scale in scales.items():
        if values[name] is not None and moves > SETTLING_BAND * scale:
            of = 'the pressure step' if name == 'P_o_percent' else 'the first overshoot'
            values[name] = None
            reasons[name] = (
                f'the step comes {t_step - since.time:.3f} s after {since.what}, before p_s '
                f'came to rest: it moves by {moves:.4g} Pa in the {SETTLED_SPAN * 1e3:g} ms '
                f'before, more than 5 % of {of}')
    return measures


class InputChanges:
    """
    The changes of the inputs other than the stepped flow, one row at a time.

    The tank pressure p_t [Pa, gauge] (a change from its level of more than its threshold,
    tank_threshold(), from the noise of the samples so far; changes within merge_time [s]
    of one belong to it), and events given by time (add_event: a fault or parameter
    change that acts from that time on). update() takes each row's time and p_t, and
    returns the Cuts that row reveals.
    """

    def __init__(self, merge_time=0.05):
        from valve_sim.analysis.steps.step_detection import StepDetector

        self.tank = StepDetector(TANK_STEP_FLOOR, merge_time)
        self.tank_samples, self.tank_count = deque(maxlen=TANK_NOISE_SAMPLES), 0
        self.events = []  # (time [s], what), sorted
        self.previous = None  # [s] the last row's time

    def tank_threshold(self, tank_pressure):
        """Take a p_t sample [Pa]; return the change that cuts [Pa], None before the first."""
        from valve_sim.analysis.steps.step_detection import noise_level

        self.tank_samples.append(tank_pressure)
        self.tank_count = count = self.tank_count + 1
        if count < TANK_NOISE_FIRST:
            return None
        if count < TANK_NOISE_EVERY or count % TANK_NOISE_EVERY == 0:
            self.tank.threshold = max(TANK_STEP_FLOOR,
                                      TANK_NOISE_FACTOR * noise_level(self.tank_samples))
        return self.tank.threshold

    def add_event(self, time, what):
        """Note a change that acts from time [s] on (its first row shows it); what: its name."""
        self.events = sorted([*self.events, (float(time), what)])

    def update(self, time, tank_pressure=None):
        """Feed one row's time [s] and p_t [Pa] (None or nan: unknown); return its Cuts."""
        cuts = []
        known = tank_pressure is not None and tank_pressure == tank_pressure
        threshold = self.tank_threshold(tank_pressure) if known else None
        if threshold is not None:
            change = self.tank.update(time, tank_pressure)
            if change and change[0] is not None:
                cuts.append(Cut(change[0], f'the tank-pressure change at {change[0]:.6f} s '
                                           f'(more than {threshold:.3g} Pa)'))
        while self.events and self.events[0][0] <= time + TIME_TOLERANCE:
            acts, what = self.events.pop(0)
            before = self.previous if self.previous is not None else time
            # a change that came late (rows already past it) cuts before its own time
            cuts.append(Cut(min(before, acts - 2 * TIME_TOLERANCE), f'{what} at {acts:.6f} s'))
        self.previous = time
        return cuts
