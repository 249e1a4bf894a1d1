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
A bench test as a file: the valve, its inputs, events and duration, and what is expected.

    scenario: stuck_main_valve            # its name (default: the file's stem)
    description: the main valve seizes; the bench's supply relief must raise the alarm
    duration: 1.0                         # [s] of model time from the first tick
    valve:                                # how valve_node starts (all optional)
      params_file: ../config/table2.yaml  # relative to this file
      parameters: {supply_pressure_limit: 21 MPa}
    inputs:
      inlet_flow: {initial: 5 L/min, changes: [{at: 0.3, step: 20 L/min}]}
      tank_pressure: {initial: 0 bar, changes: [{at: 0.5, step: 5 bar}]}  # gauge, optional
    events:                               # the fault schedule's vocabulary, and parameters
      - t: 0.2
        set: {fault.main_valve_stuck: true}
    expect:
      - alarm: {after: 0.3, within: 0.5}

Inputs: valve_sim.core.input_profile (INPUTS names those the valve takes; a file
that names none of a later one keeps working): inlet_flow [m^3/s], and tank_pressure
[Pa, gauge], optional (without it the tank stays at valve_node's tank_pressure
parameter). Events: valve_sim.core.fault_schedule's format; `set` takes fault.* and
sensor.* settings and valve_node's live parameters (ROS name or paper symbol, a
number in SI units or with a unit). Expectations: valve_sim.analysis.scenarios.expectations.
Every change, event, time and window must lie within the run (0 .. duration). Every
problem is one line naming the file, the key and what is wrong (ProfileError, an
InputFileError).
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from valve_sim.analysis.scenarios.expectations import check_times, parse_expectations
from valve_sim.analysis.steps.input_events import SettingChanges
from valve_sim.core.catalogue import CATALOGUE, section_of
from valve_sim.core.errors import InputFileError, ParameterError, ProfileError
from valve_sim.core.fault_schedule import (
    check_change,
    FaultEvent,
    parse_schedule,
    tick_index,
)
from valve_sim.core.input_documents import read_yaml
from valve_sim.core.input_files import SCENARIO_FILE
from valve_sim.core.input_profile import parse_profile
from valve_sim.core.limits import tank_pressure_problem
from valve_sim.core.parameters import (
    check_value,
    FAULT_SCHEDULE,
    load_parameters,
    PRESET_PRESSURE,
    resolve_name,
    SETTING_SPECS,
    SPECS,
)
from valve_sim.core.quantities import FLOW, LENGTH, NUMBER, parse_quantity, PRESSURE, TIME


TOP_KEYS = ('scenario', 'description', 'duration', 'valve', 'inputs', 'events', 'expect')
INPUTS = {'inlet_flow': FLOW, 'tank_pressure': PRESSURE}  # input: its dimension (tank: gauge)
INPUT_UNITS = {'inlet_flow': 'm^3/s', 'tank_pressure': 'Pa (gauge)'}
MAX_DURATION = 3600.0  # [s] of model time
NS_PER_S = 1_000_000_000
INJECTION = ('fault', 'sensor')  # catalogue sections set by name as they are, checked by events
DIMENSIONS = {'Pa': PRESSURE, 'm^3/s': FLOW, 'm': LENGTH, 's': TIME}  # parameters' units
# With a tank_pressure input: the parameters it sets, and the ambient pressure the runner
# adds to it (the topic is absolute), which must hold for the whole run.
TANK_FIXED = {
    'tank_pressure': 'inputs.tank_pressure sets the tank pressure (its initial value at start)',
    'ambient_pressure': 'the runner publishes inputs.tank_pressure as gauge + ambient_pressure',
}
# Parameters a scenario does not change while it runs (valve_node refuses the read-only
# ones; the lockstep runner steps by the tick period it started with).
FIXED = {
    'publish_rate': 'the runner steps /clock by the tick period valve_node starts with',
    'initial_inlet_flow': 'read-only: inputs.inlet_flow.initial sets it',
    FAULT_SCHEDULE: 'a scenario schedules its faults in events',
}


@dataclass
class BenchScenario:
    """A checked scenario file; times [s] from the first tick, values SI."""

    name: str
    description: str
    path: Path
    duration: float
    params_file: Path  # valve_node's --params-file, or None
    parameters: dict  # ROS name: value, set at valve_node's start
    publish_rate: float  # [Hz] the tick rate valve_node starts with
    supply_pressure_limit: float  # [Pa] at start (0: none)
    ambient_pressure: float  # [Pa] absolute, valve_node's for the whole run
    inputs: dict  # input name: core.input_profile.Profile
    events: list  # core.fault_schedule.FaultEvent, names resolved
    expectations: list
    start_values: dict = field(default_factory=dict)  # ROS name: value in effect at t = 0

    @property
    def period_ns(self):
        return round(NS_PER_S / self.publish_rate)

    @property
    def ticks(self):
        """Ticks after the first: the run's states are ticks + 1, at 0 .. duration."""
        return round(self.duration * NS_PER_S / self.period_ns)

    def tick_times(self):
        """Return the times [s] of every state of the run, from the first tick (0) to the last."""
        return np.arange(self.ticks + 1) * self.period_ns / NS_PER_S

    def event_ticks(self):
        """{tick index: merged changes} at which each event applies (after that tick's state)."""
        due = {}
        for event in self.events:
            due.setdefault(tick_index(event.time_ns, self.period_ns), {}).update(event.changes)
        return due

    def window_events(self):
        """
        [(time [s], changes)] of the events that change a value: each ends a step's window.

        Values set to what they were (from start_values on), and settings that do not
        change the model, are no change (docs/measures.md, input_events).
        """
        values, events = SettingChanges(self.start_values), []
        for event in self.events:
            changed = values.changed(event.changes)
            events += [(event.time_ns / NS_PER_S, changed)] if changed else []
        return events

    def supply_pressure_limits(self):
        """supply_pressure_limit [Pa] in effect over the tick ending at each state's time."""
        limits = np.full(self.ticks + 1, self.supply_pressure_limit)
        for tick, changes in sorted(self.event_ticks().items()):
            if 'supply_pressure_limit' in changes:
                limits[tick + 1:] = changes['supply_pressure_limit']
        return limits


def read_document(path):
    """Return the parsed YAML of a scenario file (input_files: bounded, checked, one line)."""
    return read_yaml(path, SCENARIO_FILE)


def load_scenario(path, read_bag_column=None):
    """
    Read and check a scenario file; returns a BenchScenario.

    read_bag_column: the reader of a bag series (valve_sim.recording.tick_bags.bag_column).
    Raises InputFileError: one line, the file, the key and the problem.
    """
    path = Path(path)
    document = read_document(path)
    try:
        return _scenario(document, path, read_bag_column)
    except (ProfileError, ParameterError) as error:
        raise InputFileError(f'{path}: {error}') from None


def _scenario(document, path, read_bag_column):
    if not isinstance(document, dict):
        raise ProfileError('(top level)',
                           f'expected a mapping with the keys {", ".join(TOP_KEYS)}')
    for key in document:
        if key not in TOP_KEYS:
            raise ProfileError(key, f'unknown key (keys: {", ".join(TOP_KEYS)})')
    for key in ('duration', 'inputs', 'expect'):
        if key not in document:
            raise ProfileError(key, 'missing (a scenario needs duration, inputs and expect)')
    duration = _number(document['duration'], 'duration', TIME)
    if not 0.0 < duration <= MAX_DURATION:
        raise ProfileError('duration', f'must be in (0, {MAX_DURATION:g}] s, got {duration:g} s')
    inputs = _inputs(document['inputs'], path.parent, read_bag_column)
    params_file, parameters, params, settings, injection = _valve(document.get('valve') or {},
                                                                  path.parent)
    for name, value in parameters.items():
        if name in FIXED and name != 'publish_rate':
            raise ProfileError(f'valve.parameters.{name}', FIXED[name])
    parameters['initial_inlet_flow'] = inputs['inlet_flow'].initial
    events = _events(document.get('events') or [], path)
    if 'tank_pressure' in inputs:
        _check_tank_fixed(parameters, events)
        parameters['tank_pressure'] = inputs['tank_pressure'].initial
    scenario = BenchScenario(
        name=str(document.get('scenario') or path.stem),
        description=str(document.get('description') or '').strip(),
        path=path,
        duration=duration,
        params_file=params_file,
        parameters=parameters,
        publish_rate=settings['publish_rate'],
        supply_pressure_limit=params['supply_pressure_limit'],
        ambient_pressure=settings['ambient_pressure'],
        inputs=inputs,
        events=events,
        expectations=parse_expectations(document['expect']),
        start_values={**{name: spec.default for name, spec in CATALOGUE.items()
                         if section_of(name) in INJECTION},
                      **params, **settings, **injection, **parameters},
    )
    _check_times(scenario)
    _check_inputs(scenario, params['max_inlet_flow'], params['burst_pressure'])
    return scenario


def _check_times(scenario):
    """Every change, event and expectation within the run: 0 .. duration [s]."""
    duration = scenario.duration
    for name, profile in scenario.inputs.items():
        for index, change in enumerate(profile.changes):
            if change.start > duration:
                raise ProfileError(f'inputs.{name}.changes[{index}].at',
                                   f'{change.start:g} s is after the end of the run '
                                   f'({duration:g} s): it would never apply')
    for event in scenario.events:
        if event.time_ns > duration * NS_PER_S:
            raise ProfileError('events', f'the event at {event.time_ns / NS_PER_S:g} s is after '
                               f'the end of the run ({duration:g} s): it would never apply')
    check_times(scenario.expectations, duration)


def _number(value, key, dimension):
    try:
        return parse_quantity(value, dimension)
    except ValueError as error:
        raise ProfileError(key, str(error)) from None


def _inputs(document, folder, read_bag_column):
    if not isinstance(document, dict):
        raise ProfileError('inputs', f'expected a mapping of inputs ({", ".join(INPUTS)})')
    for name in document:
        if name not in INPUTS:
            raise ProfileError(f'inputs.{name}', f'unknown input (inputs: {", ".join(INPUTS)})')
    if 'inlet_flow' not in document:
        raise ProfileError('inputs', 'needs inlet_flow')
    return {name: parse_profile(document[name], f'inputs.{name}', INPUTS[name], folder,
                                read_bag_column) for name in document}


def _parameter_value(name, value, key):
    """Return a valve parameter's value: a number, or text with a unit of its dimension."""
    if section_of(name) in INJECTION:
        return value
    spec = PRESET_PRESSURE if name == PRESET_PRESSURE.name else SETTING_SPECS.get(name) or SPECS[
        resolve_name(name)]
    if isinstance(value, str):
        return _number(value, key, DIMENSIONS.get(spec.unit, NUMBER))
    return value


def ros_name(name):
    """Return valve_node's name of a parameter given by ROS name or paper symbol."""
    if section_of(name) in (*INJECTION, 'setting', 'preset'):
        return name
    return resolve_name(name)


def start_parameter(name, value, key):
    """Return (ROS name, value) of a parameter valve_node starts with; ProfileError at key."""
    try:
        return ros_name(name), _parameter_value(name, value, key)
    except ParameterError as error:
        raise ProfileError(key, str(error)) from None


def live_change(name, value):
    """Return (ROS name, checked value) of a change while valve_node runs; ParameterError."""
    return ros_name(name), _event_value(name, value)


def _valve(document, folder):
    """(params_file, {ROS name: value}, params, settings, injection): 'valve', checked."""
    if not isinstance(document, dict):
        raise ProfileError('valve', 'expected a mapping with params_file and/or parameters')
    for key in document:
        if key not in ('params_file', 'parameters'):
            raise ProfileError(f'valve.{key}', 'unknown key (keys: params_file, parameters)')
    params_file = None
    if document.get('params_file') is not None:
        params_file = (folder / str(document['params_file'])).resolve()
    given = document.get('parameters') or {}
    if not isinstance(given, dict):
        raise ProfileError('valve.parameters', 'expected a mapping of parameter names to values')
    parameters = dict(start_parameter(name, value, f'valve.parameters.{name}')
                      for name, value in given.items())
    try:
        loaded = load_parameters(params_file, dict(parameters), with_injection=True)
        params, settings = loaded.params, loaded.settings
        for name, value in loaded.injection.items():
            check_change(name, value)
    except ParameterError as error:
        raise ProfileError('valve', str(error)) from None
    return params_file, parameters, params, settings, loaded.injection


def _event_value(name, value):
    """check() of parse_schedule: fault and sensor settings, or a live valve parameter."""
    if section_of(name) in INJECTION:
        return check_change(name, value)
    if name in FIXED:
        raise ParameterError(f"'{name}' cannot change while a scenario runs: {FIXED[name]}")
    key_name = ros_name(name)
    try:
        return check_value(key_name, _parameter_value(key_name, value, name))
    except ProfileError as error:
        raise ParameterError(str(error)) from None


def _events(items, path):
    if not isinstance(items, list):
        raise ProfileError('events', 'expected a list of {t: TIME, set: {NAME: VALUE}}')
    events = parse_schedule({'events': items}, 'events', check=_event_value)
    # paper symbols to ROS names, as valve_node's services take them
    return [FaultEvent(event.time_ns, {ros_name(name): value
                                       for name, value in event.changes.items()})
            for event in events]


def _check_tank_fixed(parameters, events):
    """With a tank_pressure input, neither it nor ambient_pressure may be set elsewhere."""
    for name, reason in TANK_FIXED.items():
        if name in parameters:
            raise ProfileError(f'valve.parameters.{name}', reason)
        for event in events:
            if name in event.changes:
                raise ProfileError(f'events.set.{name}',
                                   f'at {event.time_ns / NS_PER_S:g} s: {reason}')


def _check_inputs(scenario, max_inlet_flow, burst_pressure):
    """
    Every tick's inputs must be ones valve_node takes.

    The inlet flow 0 .. max_inlet_flow [m^3/s]; the tank pressure [Pa, gauge] not below
    vacuum and below burst_pressure (limits.tank_pressure_problem).
    """
    times = scenario.tick_times()
    flows = scenario.inputs['inlet_flow'].sample(times)
    bad = np.flatnonzero((flows < 0.0) | (flows > max_inlet_flow))
    if bad.size:
        raise ProfileError('inputs.inlet_flow', f'{flows[bad[0]]:.6g} m^3/s at {times[bad[0]]:g} '
                           f's is outside 0 .. max_inlet_flow ({max_inlet_flow:g} m^3/s)')
    if 'tank_pressure' in scenario.inputs:
        pressures = scenario.inputs['tank_pressure'].sample(times)
        for tick in (np.argmin(pressures), np.argmax(pressures)):  # the extremes say it all
            problem = tank_pressure_problem(float(pressures[tick]), burst_pressure,
                                            scenario.ambient_pressure)
            if problem:
                raise ProfileError('inputs.tank_pressure', f'at {times[tick]:g} s: {problem}')
