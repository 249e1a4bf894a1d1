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

A schedule file is read once (input_files.FAULT_SCHEDULE: a regular file of at most
1 MiB) and holds at most MAX_EVENTS events; load_schedule() returns the checked events,
which are what is applied. Run as `python -m valve_sim.core.fault_schedule FD PATH`, this
module checks the file open on descriptor FD in a process of its own (memory limited to
CHECK_MEMORY) and prints its events as JSON lines (event_lines): valve_node's way to read a
schedule set live, so that parsing it never holds the node's interpreter.
"""

from dataclasses import dataclass
import json
import os
import resource
import sys

from valve_sim.core.errors import InputFileError, ParameterError
from valve_sim.core.faults import check_fault, FAULT_NAMES
from valve_sim.core.input_documents import read_yaml
from valve_sim.core.input_files import FAULT_SCHEDULE, MAX_EVENTS, open_regular, shown
from valve_sim.core.sensors import check_sensor, SENSOR_NAMES


NS_PER_S = 1_000_000_000
MAX_TIME = 1e6  # [s] latest event time accepted (11.6 days)
CHECK_MEMORY = 2 * 1024**3  # [bytes] address space of the process that checks a file


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
        f'{shown(name)} is neither a fault (fault.*) nor a sensor setting (sensor.*) parameter'
    )


def parse_schedule(document, source='schedule', check=check_change):
    """
    Events of a parsed schedule document, sorted by time (stable); raises ParameterError.

    check(name, value) returns a change's value checked (default: fault and sensor settings).
    """
    if not isinstance(document, dict) or not isinstance(document.get('events'), list):
        raise ParameterError(f"{source}: expected a mapping with a list 'events'")
    if len(document['events']) > MAX_EVENTS:
        raise ParameterError(
            f"{source}: 'events' lists {len(document['events'])} events, more than the "
            f'{MAX_EVENTS} a schedule may hold'
        )
    events = []
    for index, event in enumerate(document['events']):
        where = f'{source}: event {index + 1}'
        if not isinstance(event, dict) or set(event) != {'t', 'set'}:
            raise ParameterError(f"{where}: expected exactly the keys 't' and 'set'")
        t = event['t']
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not 0.0 <= t <= MAX_TIME:
            raise ParameterError(
                f'{where}: t must be a time in [0, {MAX_TIME:g}] s, got {shown(t)}'
            )
        if not isinstance(event['set'], dict) or not event['set']:
            raise ParameterError(f"{where}: 'set' must map parameter names to values")
        try:
            changes = {name: check(name, value) for name, value in event['set'].items()}
        except ParameterError as error:
            raise ParameterError(f'{where}: {error}') from None
        events.append(FaultEvent(round(t * NS_PER_S), changes))
    return sorted(events, key=lambda e: e.time_ns)


def open_schedule(path):
    """
    Open a fault schedule file without reading it: a regular file within its size limit.

    Never blocks (a FIFO is refused, not waited on); raises InputFileError.
    """
    return open_regular(path, FAULT_SCHEDULE)


def load_schedule(path, stream=None):
    """
    Read a fault schedule file once and return its checked events.

    stream: the file as open_schedule(path) opened it (else it is opened here). Raises
    InputFileError (the file: not readable, not a regular file, too large, not YAML
    within input_files' limits) or ParameterError (its content, naming the event and
    the parameter).
    """
    document = read_yaml(path, FAULT_SCHEDULE, stream)
    return parse_schedule(document, f'fault schedule {path}')


def event_lines(events):
    """Yield each event as one line of JSON: [time_ns, {name: value}]."""
    for event in events:
        yield json.dumps([event.time_ns, event.changes]) + '\n'


def event_from_line(line):
    """Return the FaultEvent of one line of event_lines()."""
    time_ns, changes = json.loads(line)
    return FaultEvent(time_ns, changes)


def main(argv=None):
    """
    Check the schedule open on descriptor FD (argv: FD PATH); print the outcome as JSON lines.

    The first line is {"events": N} followed by N event lines, or {"error": message}.
    """
    descriptor, path = (sys.argv[1:] if argv is None else argv)[:2]
    resource.setrlimit(resource.RLIMIT_AS, (CHECK_MEMORY, CHECK_MEMORY))
    try:
        events = load_schedule(path, os.fdopen(int(descriptor), 'rb'))
    except (InputFileError, ParameterError, MemoryError, RecursionError) as error:
        print(json.dumps({'error': str(error) or type(error).__name__}))
        return 1
    sys.stdout.write(json.dumps({'events': len(events)}) + '\n')
    sys.stdout.writelines(event_lines(events))
    return 0


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


if __name__ == '__main__':
    sys.exit(main())
