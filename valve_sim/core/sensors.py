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
Pressure transducers: what valve_node publishes of the four chamber pressures.

Only the published samples change; the model's state never does. Per topic
(sensor.<topic>.<setting>, topic one of PRESSURE_NAMES), applied in this order to
the absolute pressure u [Pa] of each published sample:

  bandwidth   Hz   first-order lag, f += (1 - exp(-2 pi bandwidth dt)) (u - f); 0: none
  bias        Pa   added offset
  noise_std   Pa   Gaussian noise, standard deviation (seeded: sensor.noise_seed)
  resolution  Pa   quantisation step, round to the nearest multiple; 0: none
  stuck       bool output frozen (sensor fault)
  stuck_at    Pa   the frozen value (absolute); negative: the last output before sticking
  range_min   Pa   lower end of the measuring range (absolute, >= 0): output saturates there
  range_max   Pa   upper end of the measuring range (absolute); 0: no upper limit
  dropout     bool nothing published (sensor fault)

The defaults are an ideal transducer: the output is the model's pressure, never below
0 Pa absolute (the model has no cavitation; below vacuum it publishes 0 Pa). The
numbers run in one compiled kernel (sense) for the four topics. Whatever the settings,
a reading is finite and within the range, in every mode (a stuck sensor too): a
resolution is 0 or at least MIN_RESOLUTION (a finer step overflows the division), and a
reading that is still not finite is replaced by the model's pressure. Without
range_max a bias (or noise) can take a reading beyond burst_pressure, as a miscalibrated
transducer reads beyond what the valve holds.
"""

import math

import numpy as np
from valve_sim.core.catalogue import (
    NOISE_SEED,
    section,
    SENSOR_PREFIX as PREFIX,
    SENSOR_SETTINGS,
    SENSOR_TOPICS as PRESSURE_NAMES,
)
from valve_sim.core.errors import ParameterError
from valve_sim.core.input_files import shown
from valve_sim.core.jit import jit
from valve_sim.core.model import P_C, P_S
from valve_sim.core.parameters import checked_number, checked_switch


NOISE_BLOCK = 1024  # standard normal draws taken from the generator at a time
MIN_RESOLUTION = 1e-3  # [Pa] finest quantisation step; 1e-320 made every reading +inf
DEFAULTS = {spec.name: spec.default for spec in SENSOR_SETTINGS}  # an ideal transducer
SENSOR_SPECS = section('sensor')  # the catalogue's sensor.* entries
SENSOR_DOUBLE_SPECS = {n: spec for n, spec in SENSOR_SPECS.items() if spec.kind == 'double'}
SENSOR_SWITCH_SPECS = {n: spec for n, spec in SENSOR_SPECS.items() if spec.kind == 'bool'}
SENSOR_NAMES = tuple(SENSOR_DOUBLE_SPECS) + tuple(SENSOR_SWITCH_SPECS) + (NOISE_SEED.name,)


def default_settings():
    """{'sensor.<topic>.<setting>': default, 'sensor.noise_seed': 0}: ideal transducers."""
    settings = {
        f'{PREFIX}{topic}.{key}': value
        for topic in PRESSURE_NAMES
        for key, value in DEFAULTS.items()
    }
    settings[NOISE_SEED.name] = 0
    return settings


def check_sensor(name, value):
    """Return value checked for the sensor parameter name; raise ParameterError naming it."""
    if name in SENSOR_SWITCH_SPECS:
        return checked_switch(name, value, 'sensor parameter')
    if name == NOISE_SEED.name:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParameterError(
                f"sensor parameter '{name}' must be an integer, got {shown(value)}"
            )
        if not NOISE_SEED.minimum <= value <= NOISE_SEED.maximum:
            raise ParameterError(
                f"sensor parameter '{name}' = {value} is outside [0, {NOISE_SEED.maximum}]"
            )
        return value
    spec = SENSOR_DOUBLE_SPECS.get(name)
    if spec is None:
        raise ParameterError(
            f"unknown sensor setting '{name}'; known: sensor.<topic>.<setting> with topic in "
            f"{', '.join(PRESSURE_NAMES)} and setting in "
            f"{', '.join(DEFAULTS)}, and {NOISE_SEED.name}"
        )
    value = checked_number(spec, value, 'sensor parameter')
    if name.endswith('.resolution') and 0.0 < value < MIN_RESOLUTION:
        raise ParameterError(
            f"sensor parameter '{name}' (q) = {value:g} Pa must be 0 (none) or at least "
            f'{MIN_RESOLUTION:g} Pa'
        )
    return value


def checked_settings(settings, changes):
    """
    Return settings with changes applied, every value and each measuring range checked.

    Raises ParameterError naming the parameter at fault.
    """
    new = dict(settings)
    for name, value in changes.items():
        new[name] = check_sensor(name, value)
    for topic in PRESSURE_NAMES:
        low, high = new[f'{PREFIX}{topic}.range_min'], new[f'{PREFIX}{topic}.range_max']
        if high and high <= low:
            raise ParameterError(
                f"sensor parameter '{PREFIX}{topic}.range_max' = {high:g} Pa must exceed "
                f"'{PREFIX}{topic}.range_min' = {low:g} Pa (or be 0: no upper limit)"
            )
    return new


# Columns of the settings array, one row per topic (the order of DEFAULTS).
BANDWIDTH, BIAS, NOISE_STD, RESOLUTION, RANGE_MIN, RANGE_MAX, STUCK_AT, STUCK, DROPOUT = range(9)
# Columns of the memory array: lag state [Pa], last reading [Pa], time [ns], noise drawn.
FILTERED, OUTPUT, TIME, NOISE_USED = range(4)


@jit
def sense(pressures, time_ns, settings, memory, noise, out):
    """
    Write the readings [Pa absolute] of pressures [Pa absolute] at time_ns [ns] into out.

    settings: rows of the SETTING columns; memory: rows of the MEMORY columns (nan lag
    state and reading before the first sample); noise: rows of standard normal draws,
    used in order. A dropped-out topic reads nan (nothing published).
    """
    for i in range(pressures.shape[0]):
        row, state = settings[i], memory[i]
        filtered = state[FILTERED]
        if row[BANDWIDTH] > 0.0 and filtered == filtered:
            dt = max(time_ns - state[TIME], 0.0) * 1e-9
            filtered += (1.0 - math.exp(-2.0 * math.pi * row[BANDWIDTH] * dt)) * (
                pressures[i] - filtered
            )
        else:
            filtered = pressures[i]
        state[FILTERED] = filtered
        state[TIME] = time_ns
        value = filtered + row[BIAS]
        if row[NOISE_STD] > 0.0:
            value += row[NOISE_STD] * noise[i, int(state[NOISE_USED])]
            state[NOISE_USED] += 1.0
        if row[RESOLUTION] > 0.0:
            value = np.round(value / row[RESOLUTION]) * row[RESOLUTION]
        if row[STUCK] > 0.0:
            if row[STUCK_AT] >= 0.0:
                value = row[STUCK_AT]
            elif state[OUTPUT] == state[OUTPUT]:  # not nan: there was a reading before
                value = state[OUTPUT]
        if value - value != 0.0:  # not finite: never published; the model's pressure is
            value = pressures[i]
        value = max(value, row[RANGE_MIN])
        if row[RANGE_MAX] > 0.0:
            value = min(value, row[RANGE_MAX])
        state[OUTPUT] = value
        out[i] = math.nan if row[DROPOUT] > 0.0 else value


class SensorStage:
    """
    The four pressure transducers between the model and the wire.

    read(time_ns, pressures) turns the absolute pressures [Pa] of one published
    sample into what is published: a list of floats, nan for a topic that drops out.
    """

    def __init__(self, settings=None):
        count = len(PRESSURE_NAMES)
        self._settings = np.zeros((count, len(DEFAULTS)))
        self._memory = np.full((count, 4), math.nan)
        self._memory[:, NOISE_USED] = NOISE_BLOCK
        self._noise = np.zeros((count, NOISE_BLOCK))
        self._out = np.empty(count)
        self._fresh = 0  # reads left before a noise row may run out
        self._generators = None
        self._seed = None
        self.configure(checked_settings(default_settings(), settings or {}))
        # Compile (or load from numba's cache) the kernel now, not in the first tick that
        # needs it: that would stall a real-time node.
        sense(np.zeros(count), 0.0, np.zeros((count, len(DEFAULTS))), np.zeros((count, 4)),
              self._noise, np.empty(count))

    def configure(self, settings):
        """Use new settings (as checked_settings returns them); the transducers' memory stays."""
        self.settings = settings
        for row, topic in enumerate(PRESSURE_NAMES):
            for column, key in enumerate(DEFAULTS):
                self._settings[row, column] = float(settings[f'{PREFIX}{topic}.{key}'])
        seed = settings[NOISE_SEED.name]
        if seed != self._seed:
            self._seed = seed
            self._generators = [
                np.random.default_rng([seed, row]) for row in range(len(PRESSURE_NAMES))
            ]
            self._memory[:, NOISE_USED] = NOISE_BLOCK
            self._fresh = 0
        defaults = np.array([float(v) for v in DEFAULTS.values()])
        self.ideal = bool(np.all(self._settings == defaults))

    def _draw(self):
        """Refill the noise rows that are used up; return the reads before one can run out."""
        for row, generator in enumerate(self._generators):
            if self._memory[row, NOISE_USED] >= NOISE_BLOCK:
                self._noise[row] = generator.standard_normal(NOISE_BLOCK)
                self._memory[row, NOISE_USED] = 0.0
        return int(NOISE_BLOCK - self._memory[:, NOISE_USED].max())

    def checked(self, changes):
        """Return the settings {name: value} of sensor parameters would give; raise if bad."""
        return checked_settings(self.settings, changes)

    def change(self, changes):
        """Apply {name: value} of sensor parameters, checked; raises ParameterError."""
        if changes:
            self.configure(checked_settings(self.settings, changes))

    def read(self, time_ns, pressures):
        """Return the readings [Pa absolute] of pressures [Pa absolute]; nan: dropped out."""
        if self.ideal:
            return [max(p, 0.0) for p in pressures]
        if self._fresh == 0:
            self._fresh = self._draw()
        self._fresh -= 1
        sense(
            np.asarray(pressures, dtype=float),
            float(time_ns),
            self._settings,
            self._memory,
            self._noise,
            self._out,
        )
        return self._out.tolist()

    def rebase(self, shift_ns):
        """Move the time of the last sample by shift_ns [ns]: the clock jumped (new time base)."""
        self._memory[:, TIME] += shift_ns

    def describe_faults(self):
        """Names of the sensor faults and non-ideal settings in effect, for diagnostics."""
        active = []
        for name, value in self.settings.items():
            default = DEFAULTS.get(name.rsplit('.', 1)[-1])
            if name != NOISE_SEED.name and value != default:
                active.append(name if isinstance(value, bool) else f'{name} = {value:g}')
        return active

    def dropped_topics(self):
        """Topics that publish nothing (dropout)."""
        return [t for t, row in zip(PRESSURE_NAMES, self._settings) if row[DROPOUT]]


def read_waveforms(waveforms, settings, tick_interval, ambient_pressure):
    """
    Return (tick indices, readings) of an offline run as valve_node would publish them.

    waveforms: simulation.Waveforms (its events change sensor settings at their ticks);
    settings: sensor settings at the start; every sample tick_interval [s] apart is a
    tick. readings: array (ticks, 4) [Pa absolute], nan where nothing is published.
    """
    interval = waveforms.time[1] - waveforms.time[0]
    every = max(1, round(tick_interval / interval))
    indices = np.arange(0, len(waveforms.time), every)
    stage = SensorStage(settings)
    changes = {round(t / interval): c for t, c in waveforms.events}
    readings = np.empty((len(indices), len(PRESSURE_NAMES)))
    for row, index in enumerate(indices):
        if index in changes:
            stage.change({n: v for n, v in changes[index].items() if n in SENSOR_NAMES})
        time_ns = round(waveforms.time[index] * 1e9)
        readings[row] = stage.read(
            time_ns, waveforms.states[index, P_S:P_C + 1] + ambient_pressure
        )
    return indices, readings
