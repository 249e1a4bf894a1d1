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
What a bench scenario expects of the valve, and each expectation judged on its recording.

    expect:
      - measures: {at: 0.25, P_1_percent: {max: 3.5}, T_s_ms: {min: 450, max: 650}}
      - never_above: {signal: supply_pressure, value: 7.5 MPa, from: 0.3}
      - never_below: {signal: supply_pressure, value: 6.9 MPa}
      - alarm: {after: 0.5, within: 0.5}
      - no_alarm: {to: 0.5}
      - steady: {signal: supply_pressure, flow: 20 L/min, min: 7.0 MPa, max: 7.1 MPa}

Times [s] count from the first tick; signals are valve_sim.analysis.scenarios.tick_series.SIGNALS
(pressures gauge [Pa]); the six measures are docs/measures.md's, of the steps the
analyser's own step analysis finds. Each expectation gives one Check per limit: what
was measured, the limit, and whether it holds. The alarm is valve_node's overpressure
alarm (valve_sim.core.faults.at_supply_limit), judged on the recorded supply_pressure.
check_times() refuses any time or window outside the run (0 .. its duration), inverted,
or negative, before the run; a check whose window holds no sample fails with that
reason, in every kind, never passes.

Over 400 lines on purpose: each kind of expectation is read and judged here, side by
side, so that a kind's keys, limits and check are in one place.
"""

from dataclasses import dataclass
import math

import numpy as np
from valve_sim.analysis.scenarios.tick_series import SIGNALS
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.core.errors import ProfileError
from valve_sim.core.faults import at_supply_limit
from valve_sim.core.quantities import FLOW, NUMBER, parse_quantity, TIME, with_unit


STEP_MATCH = 0.01  # [s] a step detected this close to `at` is the step meant
STEADY_WINDOW = 0.1  # [s] the steady value: the mean over the hold's last 0.1 s by default
NEAR = 1e-12  # [s] times this close count as equal (a tick's time in floating point)
MEASURE_UNITS = {'P_o_percent': '%', 'P_1_percent': '%', 'T_1_ms': 'ms', 'r_d': '',
                 'T_d_ms': 'ms', 'T_s_ms': 'ms'}


@dataclass
class Check:
    """
    One limit judged: its name, whether it holds, the measured value (SI, None: none) in unit.

    limit, detail and shown (the measured value in a person's unit) are text.
    """

    name: str
    passed: bool
    measured: float = None
    unit: str = ''
    limit: str = ''
    detail: str = ''
    shown: str = ''

    def __post_init__(self):
        """Keep plain Python values (JSON): numpy's bool and float64 are not."""
        self.passed = bool(self.passed)
        self.measured = None if self.measured is None else float(self.measured)

    def as_dict(self):
        """Return the check as a JSON-ready dict."""
        return dict(self.__dict__)


def _text(value, dimension):
    """Return value as text: a quantities dimension's display unit, or a measure's unit."""
    if value is None:
        return 'none'
    if isinstance(dimension, str):
        return f'{value:.6g} {dimension}'.rstrip()
    return with_unit(value, dimension)


def _check(name, passed, measured, dimension, limit, detail):
    """Build a Check of a value of dimension (a quantities table, or a measure's unit)."""
    unit = dimension if isinstance(dimension, str) else dimension[1]
    return Check(name, passed, measured, unit, limit, detail, _text(measured, dimension))


def _quantity(value, key, dimension):
    try:
        return parse_quantity(value, dimension)
    except ValueError as error:
        raise ProfileError(key, str(error)) from None


def _keys(document, key, required, optional=()):
    if not isinstance(document, dict):
        raise ProfileError(key, 'expected a mapping')
    for name in document:
        if name not in required + optional:
            allowed = ', '.join(required + optional)
            raise ProfileError(f'{key}.{name}', f'unknown key (allowed: {allowed})')
    for name in required:
        if name not in document:
            raise ProfileError(key, f"needs '{name}'")


def _signal(document, key):
    name = document['signal']
    if name not in SIGNALS:
        raise ProfileError(f'{key}.signal',
                           f'unknown signal {name!r} (signals: {", ".join(SIGNALS)})')
    return name


def _bounds(document, key, dimension):
    """Return (min, max) of a {min, max} mapping, at least one given; None where not."""
    low, high = (_quantity(document[bound], f'{key}.{bound}', dimension)
                 if bound in document else None for bound in ('min', 'max'))
    if low is None and high is None:
        raise ProfileError(key, "needs 'min' or 'max'")
    if low is not None and high is not None and low > high:
        raise ProfileError(key, f'min {low:g} is above max {high:g}')
    return low, high


def _window(document, key):
    """Return (from, to) [s] of a document's optional 'from' and 'to'; None where not given."""
    return tuple(_quantity(document[name], f'{key}.{name}', TIME) if name in document else None
                 for name in ('from', 'to'))


def _within(value, low, high):
    return (value is not None and math.isfinite(value) and (low is None or value >= low)
            and (high is None or value <= high))


def _bounds_text(low, high, dimension):
    if low is None:
        return f'<= {_text(high, dimension)}'
    if high is None:
        return f'>= {_text(low, dimension)}'
    return f'{_text(low, dimension)} .. {_text(high, dimension)}'


def _no_samples(label, dimension, limit, start, end, series):
    """Return the failed Check of a window (start, end) [s] without a sample of series."""
    held = (f'the run has samples from {series.time[0]:.6g} to {series.time[-1]:.6g} s'
            if len(series) else 'the run has no samples')
    return _check(label, False, None, dimension, limit,
                  f'no samples from {start or 0:g} s to '
                  f'{"the end" if end is None else f"{end:g} s"} ({held})')


def _time_problem(value, duration, what):
    """Why a time [s] (None: not given) lies outside the run 0 .. duration, or None."""
    if value is None or -NEAR <= value <= duration + NEAR:
        return None
    where = 'before the start' if value < 0 else 'after the end'
    return f'{what} {value:g} s is {where} of the run (0 .. {duration:g} s)'


def _check_window(start, end, duration, key):
    """Refuse a window (from, to) [s] outside the run or inverted; ProfileError at key."""
    for name, value in (('from', start), ('to', end)):
        problem = _time_problem(value, duration, name)
        if problem:
            raise ProfileError(f'{key}.{name}', problem)
    if start is not None and end is not None and start > end:
        raise ProfileError(key, f'the window is inverted: from {start:g} s is after to {end:g} s')


def check_times(expectations, duration):
    """Refuse any expectation's time or window that is outside a run of duration [s]."""
    for expectation in expectations:
        expectation.check_times(duration)


def _window_text(start, end):
    if start is None and end is None:
        return 'the whole run'
    return f'{start or 0:g} s to {"the end" if end is None else f"{end:g} s"}'


class Measures:
    """The six measures of one step within limits: {at: T | step: N, MEASURE: {min, max}}."""

    def __init__(self, document, key):
        _keys(document, key, (), ('at', 'step') + MEASURE_NAMES)
        self.key = key
        if ('at' in document) == ('step' in document):
            raise ProfileError(key, "needs either 'at' (the step's time [s]) or 'step' (its "
                               'number, from 1)')
        self.at = _quantity(document['at'], f'{key}.at', TIME) if 'at' in document else None
        self.number = document.get('step')
        if self.at is None and (isinstance(self.number, bool) or not isinstance(self.number, int)
                                or self.number < 1):
            raise ProfileError(f'{key}.step',
                               f'expected a step number from 1, got {self.number!r}')
        self.limits = {name: _bounds(document[name], f'{key}.{name}', NUMBER)
                       for name in MEASURE_NAMES if name in document}
        if not self.limits:
            raise ProfileError(key, 'needs a limit of at least one measure '
                               f'({", ".join(MEASURE_NAMES)})')

    def check_times(self, duration):
        problem = _time_problem(self.at, duration, 'the step at')
        if problem:
            raise ProfileError(f'{self.key}.at', problem)

    def _step(self, steps):
        """Return (the step record meant or None, which step in words, what was detected)."""
        if self.at is None:
            found = steps[self.number - 1] if self.number <= len(steps) else None
            return found, f'step {self.number}', f'{len(steps)} step(s) detected'
        near = [step for step in steps if abs(step['t_step'] - self.at) <= STEP_MATCH]
        found = min(near, key=lambda step: abs(step['t_step'] - self.at)) if near else None
        detected = ', '.join(f'{step["t_step"]:.4g} s' for step in steps) or 'none'
        return found, f'the step at {self.at:g} s', f'steps detected at: {detected}'

    def evaluate(self, series, context):
        step, which, detected = self._step(context.steps)
        checks = []
        for name, (low, high) in self.limits.items():
            unit, limit = MEASURE_UNITS[name], _bounds_text(low, high, MEASURE_UNITS[name])
            label = f'measures of {which}: {name} {limit}'
            if step is None:
                checks.append(_check(label, False, None, unit, limit,
                                     f'no such step ({detected})'))
                continue
            value = step[name]
            detail = (f'step at {step["t_step"]:.6g} s' if value is not None
                      else f'undefined: {step["reasons"].get(name, "no value")}')
            checks.append(_check(label, _within(value, low, high), value, unit, limit, detail))
        return checks


class Bound:
    """A signal never above (or below) a value: {signal: S, value: V, from: T0, to: T1}."""

    def __init__(self, document, key, above):
        _keys(document, key, ('signal', 'value'), ('from', 'to'))
        self.above, self.signal = above, _signal(document, key)
        self.dimension = SIGNALS[self.signal][0]
        self.value = _quantity(document['value'], f'{key}.value', self.dimension)
        self.start, self.end, self.key = *_window(document, key), key

    def check_times(self, duration):
        _check_window(self.start, self.end, duration, self.key)

    def evaluate(self, series, context):
        mask = series.window(self.start, self.end) & np.isfinite(series[self.signal])
        label = (f'{self.signal} never {"above" if self.above else "below"} '
                 f'{with_unit(self.value, self.dimension)} ({_window_text(self.start, self.end)})')
        limit = (_bounds_text(None, self.value, self.dimension) if self.above
                 else _bounds_text(self.value, None, self.dimension))
        if not mask.any():
            return [_no_samples(label, self.dimension, limit, self.start, self.end, series)]
        values, times = series[self.signal][mask], series.time[mask]
        index = int(np.argmax(values) if self.above else np.argmin(values))
        extreme = float(values[index])
        passed = extreme <= self.value if self.above else extreme >= self.value
        where = f'{"highest" if self.above else "lowest"} at {times[index]:.6g} s'
        return [_check(label, passed, extreme, self.dimension, limit, where)]


def alarm_times(series, limits):
    """Return the times [s] of the rows at which p_s is at supply_pressure_limit (per row [Pa])."""
    at_limit = [at_supply_limit(p, limit) for p, limit in zip(series['supply_pressure'], limits)]
    return series.time[np.array(at_limit, bool)] if len(series) else series.time


class Alarm:
    """The overpressure alarm raised within a time after another: {after: T, within: D}."""

    def __init__(self, document, key):
        _keys(document, key, ('after', 'within'))
        self.after = _quantity(document['after'], f'{key}.after', TIME)
        self.within = _quantity(document['within'], f'{key}.within', TIME)
        self.key = key

    def check_times(self, duration):
        problem = _time_problem(self.after, duration, 'after')
        if problem:
            raise ProfileError(f'{self.key}.after', problem)
        if self.within < 0:
            raise ProfileError(f'{self.key}.within', f'must be a time >= 0 s after '
                               f'{self.after:g} s, got {self.within:g}')

    def evaluate(self, series, context):
        label = f'overpressure alarm within {self.within:g} s after {self.after:g} s'
        limit = f'<= {self.within:g} s'
        if not series.window(self.after).any():
            return [_no_samples(label, TIME, limit, self.after, None, series)]
        raised = context.alarm_times[context.alarm_times >= self.after - NEAR]
        if raised.size:
            delay = float(raised[0] - self.after)
            return [_check(label, delay <= self.within + NEAR, delay, TIME, limit,
                           f'raised at {raised[0]:.6g} s')]
        unlimited = not np.any(context.limits[series.time >= self.after - NEAR])
        why = ('supply_pressure_limit is 0 (no limit) there' if unlimited
               else 'p_s never reached supply_pressure_limit')
        end = series.time[-1] if len(series) else 0.0
        return [_check(label, False, None, TIME, limit, f'not raised by the end ({end:.6g} s): '
                       f'{why}')]


class NoAlarm:
    """No overpressure alarm in a window: {from: T0, to: T1} (both optional)."""

    def __init__(self, document, key):
        document = document or {}
        _keys(document, key, (), ('from', 'to'))
        self.start, self.end, self.key = *_window(document, key), key

    def check_times(self, duration):
        _check_window(self.start, self.end, duration, self.key)

    def evaluate(self, series, context):
        label = f'no overpressure alarm ({_window_text(self.start, self.end)})'
        if not series.window(self.start, self.end).any():
            return [_no_samples(label, TIME, 'never', self.start, self.end, series)]
        times = context.alarm_times
        end = math.inf if self.end is None else self.end
        inside = times[(times >= (self.start or 0.0) - NEAR) & (times <= end + NEAR)]
        if inside.size:
            return [_check(label, False, inside[0], TIME, 'never', f'raised at {inside[0]:.6g} s')]
        return [_check(label, True, None, TIME, 'never', 'not raised')]


class Steady:
    """A signal's steady value at an inlet flow within a band: {signal, flow, min, max, window}."""

    def __init__(self, document, key):
        _keys(document, key, ('signal', 'flow'), ('min', 'max', 'window'))
        self.signal = _signal(document, key)
        self.dimension = SIGNALS[self.signal][0]
        self.flow = _quantity(document['flow'], f'{key}.flow', FLOW)
        self.low, self.high = _bounds(document, key, self.dimension)
        self.span = _quantity(document.get('window', STEADY_WINDOW), f'{key}.window', TIME)
        self.key = key

    def check_times(self, duration):
        if not 0.0 < self.span <= duration + NEAR:
            raise ProfileError(f'{self.key}.window', f'must be in (0, {duration:g}] s (the run), '
                               f'got {self.span:g} s')

    def evaluate(self, series, context):
        """Judge the mean over the last `window` of the last hold of the flow."""
        limit = _bounds_text(self.low, self.high, self.dimension)
        label = f'steady {self.signal} at {with_unit(self.flow, FLOW)} {limit}'
        held = np.isclose(series['inlet_flow'], self.flow, rtol=1e-9, atol=1e-12)
        if not held.any():
            return [_check(label, False, None, self.dimension, limit,
                           f'the inlet flow was never {with_unit(self.flow, FLOW)}')]
        last = len(held) - 1 - int(np.argmax(held[::-1]))
        first = last
        while first > 0 and held[first - 1]:
            first -= 1
        start, end = series.time[first], series.time[last]
        if end - start < self.span - NEAR:
            return [_check(label, False, None, self.dimension, limit,
                           f'held for {end - start:.6g} s only ({start:.6g} to {end:.6g} s), '
                           f'less than the window of {self.span:g} s')]
        values = series[self.signal][series.window(end - self.span, end)]
        values = values[~np.isnan(values)]
        if not values.size:
            return [_no_samples(label, self.dimension, limit, end - self.span, end, series)]
        mean, spread = float(np.nanmean(values)), float(np.nanmax(values) - np.nanmin(values))
        detail = (f'mean over {end - self.span:.6g} to {end:.6g} s, spread '
                  f'{with_unit(spread, self.dimension)}')
        return [_check(label, _within(mean, self.low, self.high), mean, self.dimension, limit,
                       detail)]


KINDS = {
    'measures': Measures,
    'never_above': lambda document, key: Bound(document, key, True),
    'never_below': lambda document, key: Bound(document, key, False),
    'alarm': Alarm,
    'no_alarm': NoAlarm,
    'steady': Steady,
}


def parse_expectations(items, key='expect'):
    """Return the expectations of a scenario's 'expect' list; ProfileError names the key."""
    if not isinstance(items, list) or not items:
        raise ProfileError(key, 'expected a list of at least one expectation')
    expectations = []
    for index, item in enumerate(items):
        where = f'{key}[{index}]'
        if not isinstance(item, dict) or len(item) != 1:
            raise ProfileError(where, 'expected one kind, {KIND: {...}}, KIND one of '
                               + ', '.join(KINDS))
        (kind, document), = item.items()
        if kind not in KINDS:
            raise ProfileError(f'{where}.{kind}',
                               f'unknown expectation (kinds: {", ".join(KINDS)})')
        expectations.append(KINDS[kind](document, f'{where}.{kind}'))
    return expectations


@dataclass
class Context:
    """What the expectations judge besides the series: steps, limits and alarm times."""

    steps: list  # step records, times [s] from the first tick
    limits: np.ndarray  # [Pa] supply_pressure_limit in effect at each row (0: none)
    alarm_times: np.ndarray  # [s] rows at which the alarm is raised


def evaluate(expectations, series, limits, steps=None):
    """
    Judge every expectation on a TickSeries; returns the list of Checks.

    limits: supply_pressure_limit [Pa] in effect at each row of series; steps: its step
    records (default: series.steps()).
    """
    limits = np.asarray(limits, float)
    steps = series.steps() if steps is None else steps
    context = Context(steps, limits, alarm_times(series, limits))
    return [check for expectation in expectations
            for check in expectation.evaluate(series, context)]
