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
An input of the valve as a function of time: a start value and changes at given times.

    inlet_flow:                                  # [m^3/s], or with a unit
      initial: 5 L/min
      changes:
        - {at: 0.25, step: 20 L/min}
        - {at: 0.6, ramp: 10 L/min, over: 0.1}
        - {at: 1.0, sine: {amplitude: 2 L/min, frequency: 5}, over: 0.4}
        - {at: 1.5, series: {csv: rig.csv, time: t, value: q, unit: L/min}}

Times [s] count from the first tick. Each change holds from its `at` until the next
one; `base` below is the input's value just before the change:

  step     the value from `at` on
  ramp     linear from base to the value over `over` [s], then held
  sine     base + amplitude sin(2 pi frequency (t - at) + phase) for `over` [s]
           (default: until the next change), then base again
  series   a recorded column, replayed from `at` (its first sample at `at`), linear
           between samples, its last value held after it: {csv: FILE, time: COLUMN,
           value: COLUMN} or {bag: FILE, topic: TOPIC} (Float64 data, a FluidPressure,
           or {joint: NAME, field: position|velocity|effort} of a JointState), with
           `unit` the unit of the values (default SI) and, for a bag, `clock: header`
           (default) or `receive`

An input is sampled at the start of every tick: the value at t_k is applied over
the tick from t_k to t_k+1 (a step at t lands at the first tick at or after it).
Pure data: a bag column is read by the caller's read_bag_column (valve_sim.recording
reads bags), so this module needs no bag library.
"""

import csv
from dataclasses import dataclass
import io
import math
from pathlib import Path

import numpy as np
from valve_sim.core.errors import InputFileError, ProfileError
from valve_sim.core.input_files import INPUT_CSV, read_text
from valve_sim.core.quantities import FREQUENCY, NUMBER, parse_quantity, TIME


KINDS = ('step', 'ramp', 'sine', 'series')


@dataclass(frozen=True)
class Change:
    """One change of an input from time start [s]: kind, target value, duration, samples."""

    start: float
    kind: str
    value: float = 0.0  # step, ramp: the new value [SI]
    duration: float = math.inf  # ramp, sine: [s]
    amplitude: float = 0.0  # sine [SI]
    frequency: float = 0.0  # sine [Hz]
    phase: float = 0.0  # sine [rad]
    times: tuple = ()  # series: [s] from its first sample
    values: tuple = ()  # series [SI]


@dataclass(frozen=True)
class Profile:
    """An input's initial value [SI] and its changes in time order."""

    initial: float
    changes: tuple = ()

    def sample(self, times):
        """
        Return the input at times [s] (an array): what each tick from there applies.

        Each change shapes only its own span of the times, found by bisection: the time
        grows with changes + times, not with their product.
        """
        times = np.asarray(times, dtype=float)
        values = np.full(times.shape, self.initial)
        order = np.argsort(times.ravel(), kind='stable')
        flat_times, flat_values = times.ravel()[order], values.ravel()
        edges = np.searchsorted(flat_times, [change.start for change in self.changes], 'left')
        base = self.initial
        followers = self.changes[1:] + (None,)
        for number, (change, following) in enumerate(zip(self.changes, followers)):
            end = math.inf if following is None else following.start
            last = edges[number + 1] if following is not None else len(flat_times)
            inside = order[edges[number]:last]
            flat_values[inside] = _shape(change, base, flat_times[edges[number]:last]
                                         - change.start)
            if following is not None:  # the base of the next change: this one's value there
                base = float(_shape(change, base, np.array([end - change.start]))[0])
        return values


def _shape(change, base, elapsed):
    """Return the values of change at elapsed [s] after its start, from base."""
    if change.kind == 'step':
        return np.full(elapsed.shape, change.value)
    if change.kind == 'ramp':
        progress = np.clip(elapsed / change.duration, 0.0, 1.0) if change.duration > 0 else 1.0
        return base + (change.value - base) * progress
    if change.kind == 'sine':
        wave = change.amplitude * np.sin(2 * np.pi * change.frequency * elapsed + change.phase)
        return np.where(elapsed < change.duration, base + wave, base)
    return np.interp(elapsed, change.times, change.values)


def parse_profile(document, key, dimension, folder, read_bag_column=None):
    """
    Return the Profile of an input's document (a number: constant; or initial + changes).

    key: its dotted path for messages; dimension: its quantities.* unit table;
    folder: where relative file names point (the scenario's folder);
    read_bag_column(path, topic, joint, field, clock) -> (times [s], values) reads a
    bag for a series. Raises ProfileError naming the key.
    """
    if not isinstance(document, dict):
        return Profile(_quantity(document, key, dimension))
    _only(document, ('initial', 'changes'), key)
    if 'initial' not in document:
        raise ProfileError(key, "needs 'initial', the value the valve starts at")
    initial = _quantity(document['initial'], f'{key}.initial', dimension)
    changes, previous = [], 0.0
    items = document.get('changes') or []
    if not isinstance(items, list):
        raise ProfileError(f'{key}.changes', 'expected a list of changes')
    for index, item in enumerate(items):
        where = f'{key}.changes[{index}]'
        change = _change(item, where, dimension, folder, read_bag_column)
        if change.start < previous:
            raise ProfileError(f'{where}.at', f'{change.start:g} s is before the change before it')
        previous = change.start
        changes.append(change)
    return Profile(initial, tuple(changes))


def _only(document, allowed, key):
    unknown = [name for name in document if name not in allowed]
    if unknown:
        raise ProfileError(f'{key}.{unknown[0]}', f'unknown key (allowed: {", ".join(allowed)})')


def _quantity(value, key, dimension):
    try:
        return parse_quantity(value, dimension)
    except ValueError as error:
        raise ProfileError(key, str(error)) from None


def _duration(document, key, default=None):
    if 'over' not in document:
        if default is None:
            raise ProfileError(key, "needs 'over', its duration [s]")
        return default
    value = _quantity(document['over'], f'{key}.over', TIME)
    if value < 0:
        raise ProfileError(f'{key}.over', f'a duration must be >= 0, got {value:g} s')
    return value


def _change(item, key, dimension, folder, read_bag_column):
    """Parse one change {at: T, KIND: ..., [over: D]}."""
    if not isinstance(item, dict):
        raise ProfileError(key, 'expected a mapping such as {at: 0.25, step: 20 L/min}')
    _only(item, ('at', 'over') + KINDS, key)
    kinds = [kind for kind in KINDS if kind in item]
    if len(kinds) != 1:
        raise ProfileError(key, f'needs exactly one of {", ".join(KINDS)}')
    kind = kinds[0]
    if 'over' in item and kind not in ('ramp', 'sine'):
        raise ProfileError(f'{key}.over', f"a {kind} has no duration ('over' is for ramp, sine)")
    if 'at' not in item:
        raise ProfileError(key, "needs 'at', the time [s] it begins")
    start = _quantity(item['at'], f'{key}.at', TIME)
    if start < 0:
        raise ProfileError(f'{key}.at', f'a time must be >= 0, got {start:g} s')
    where = f'{key}.{kind}'
    if kind == 'step':
        return Change(start, kind, value=_quantity(item[kind], where, dimension))
    if kind == 'ramp':
        return Change(start, kind, value=_quantity(item[kind], where, dimension),
                      duration=_duration(item, key))
    if kind == 'sine':
        sine = item[kind]
        if not isinstance(sine, dict):
            raise ProfileError(where, 'expected {amplitude: A, frequency: F, phase: P}')
        _only(sine, ('amplitude', 'frequency', 'phase'), where)
        for needed in ('amplitude', 'frequency'):
            if needed not in sine:
                raise ProfileError(where, f"needs '{needed}'")
        frequency = _quantity(sine['frequency'], f'{where}.frequency', FREQUENCY)
        if frequency <= 0:
            raise ProfileError(f'{where}.frequency', f'must be > 0, got {frequency:g} Hz')
        return Change(start, kind, amplitude=_quantity(sine['amplitude'], f'{where}.amplitude',
                                                       dimension),
                      frequency=frequency,
                      phase=_quantity(sine.get('phase', 0.0), f'{where}.phase', NUMBER),
                      duration=_duration(item, key, math.inf))
    times, values = _series(item[kind], where, dimension, folder, read_bag_column)
    return Change(start, kind, times=tuple(times - times[0]), values=tuple(values))


def _series(document, key, dimension, folder, read_bag_column):
    """Return (times [s], values [SI]) of a series' csv or bag column."""
    if not isinstance(document, dict) or ('csv' in document) == ('bag' in document):
        raise ProfileError(key, 'expected {csv: FILE, time: COLUMN, value: COLUMN} or '
                           '{bag: FILE, topic: TOPIC}')
    source = 'csv' if 'csv' in document else 'bag'
    allowed = (('csv', 'time', 'value', 'unit') if source == 'csv'
               else ('bag', 'topic', 'joint', 'field', 'clock', 'unit'))
    _only(document, allowed, key)
    unit = document.get('unit', dimension[1])
    if unit not in dimension[2]:
        raise ProfileError(f'{key}.unit', f'unknown {dimension[0]} unit {unit!r} '
                           f'(units: {", ".join(dimension[2])})')
    path = Path(folder) / str(document[source])
    try:
        if source == 'csv':
            times, values = _csv_column(path, document, key)
        else:
            if 'topic' not in document:
                raise ProfileError(key, "needs 'topic', the bag's topic to replay")
            times, values = read_bag_column(
                path, document['topic'], document.get('joint'), document.get('field'),
                document.get('clock', 'header'))
    except InputFileError as error:
        if isinstance(error, ProfileError):
            raise
        raise ProfileError(f'{key}.{source}', str(error)) from None
    times, values = np.asarray(times, float), np.asarray(values, float) * dimension[2][unit]
    if times.size == 0:
        raise ProfileError(f'{key}.{source}', f'{path} holds no samples')
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(values))):
        raise ProfileError(f'{key}.{source}', f'{path} holds a sample that is not finite')
    if np.any(np.diff(times) <= 0):
        raise ProfileError(f'{key}.{source}', f'the times of {path} do not increase')
    return times, values


def _csv_column(path, document, key):
    """Return (times, values) of two named columns of a CSV file with a header row."""
    for needed in ('time', 'value'):
        if needed not in document:
            raise ProfileError(key, f"needs '{needed}', the name of its column")
    text = read_text(path, INPUT_CSV)
    try:
        rows = list(csv.DictReader(io.StringIO(text, newline='')))
    except csv.Error as error:
        raise InputFileError(f'{INPUT_CSV.name} {path}: {error}') from None
    columns = rows[0].keys() if rows else ()
    for needed in ('time', 'value'):
        if document[needed] not in columns:
            raise ProfileError(f'{key}.{needed}', f'{path} has no column {document[needed]!r} '
                               f'(columns: {", ".join(columns) or "none"})')
    try:
        return ([float(row[document['time']]) for row in rows],
                [float(row[document['value']]) for row in rows])
    except (TypeError, ValueError) as error:
        raise ProfileError(key, f'{path}: a row is not a number: {error}') from None
