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
Fault scenario files: at t = ... s set these fault and sensor parameters to ...

    events:
      - t: 0.2                              # [s] from the first tick
        set:
          fault.damping_orifice_blockage: 0.5
          sensor.supply_pressure.noise_std: 2000.0
      - t: 0.6
        set: {fault.main_valve_stuck: true}

t counts from the node's first tick on the clock it follows (/clock with
use_sim_time), offline from the start of the run. An event takes effect at the
first tick at or after its time (tick_index): valve_node and `valve-sim simulate
--faults` apply it there, after the model has reached that tick and before the
tick's sample is published, so one file gives the same response offline and live.
"""

from dataclasses import dataclass
from pathlib import Path

from valve_sim.core.errors import InputFileError
from valve_sim.core.faults import check_fault, FAULT_NAMES
from valve_sim.core.parameters import ParameterError
from valve_sim.core.sensors import check_sensor, SENSOR_NAMES
import yaml


NS_PER_S = 1_000_000_000
MAX_TIME = 1e6  # [s] latest event time accepted (11.6 days)


@dataclass(frozen=True)
class FaultEvent:
    """time_ns [ns] from the first tick; changes {parameter name: value}."""

    time_ns: int
    changes: dict


def check_change(name, value):
    """Return value checked for a fault or sensor parameter; raise ParameterError naming it."""
    if name in FAULT_NAMES:
        return check_fault(name, value)
    if name in SENSOR_NAMES:
        return check_sensor(name, value)
    raise ParameterError(
        f"'{name}' is neither a fault (fault.*) nor a sensor setting (sensor.*) parameter"
    )


def parse_schedule(document, source='schedule', check=check_change):
    """
    Events of a parsed schedule document, sorted by time (stable); raises ParameterError.

    check(name, value) returns a change's value checked (default: fault and sensor settings).
    """
    if not isinstance(document, dict) or not isinstance(document.get('events'), list):
        raise ParameterError(f"{source}: expected a mapping with a list 'events'")
    events = []
    for index, event in enumerate(document['events']):
        where = f'{source}: event {index + 1}'
        if not isinstance(event, dict) or set(event) != {'t', 'set'}:
            raise ParameterError(f"{where}: expected exactly the keys 't' and 'set'")
        t = event['t']
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not 0.0 <= t <= MAX_TIME:
            raise ParameterError(f'{where}: t must be a time in [0, {MAX_TIME:g}] s, got {t!r}')
        if not isinstance(event['set'], dict) or not event['set']:
            raise ParameterError(f"{where}: 'set' must map parameter names to values")
        try:
            changes = {name: check(name, value) for name, value in event['set'].items()}
        except ParameterError as error:
            raise ParameterError(f'{where}: {error}') from None
        events.append(FaultEvent(round(t * NS_PER_S), changes))
    return sorted(events, key=lambda e: e.time_ns)


def load_schedule(path):
    """Read and check a fault schedule file; raises InputFileError or ParameterError."""
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text())
    except OSError as error:
        raise InputFileError(f'cannot read fault schedule {path}: {error.strerror}') from error
    except yaml.YAMLError as error:
        raise InputFileError(f'fault schedule {path} is not valid YAML: {error}') from error
    return parse_schedule(document, str(path))


def tick_index(time_ns, tick_ns):
    """Index of the first tick at or after time_ns, ticks every tick_ns from 0 [ns]."""
    return -(-time_ns // tick_ns)


class Schedule:
    """The events not yet applied; due(elapsed_ns) hands out those whose time has come."""

    def __init__(self, events=()):
        self.events = list(events)
        self._next = 0

    def due(self, elapsed_ns):
        """Return the merged changes of the events due at elapsed_ns [ns], not handed out yet."""
        changes = {}
        while self._next < len(self.events) and self.events[self._next].time_ns <= elapsed_ns:
            changes.update(self.events[self._next].changes)
            self._next += 1
        return changes

    def pending(self):
        return len(self.events) - self._next
