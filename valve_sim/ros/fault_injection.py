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
valve_node's faults and sensors: parameters, schedule, sensor stage and alarms.

The parameters fault.* and sensor.* (descriptors with unit, meaning and limits) and
fault_schedule (a schedule file, valve_sim.core.fault_schedule) are declared here, as
the parameter catalogue (valve_sim.core.catalogue) has them;
FaultInjection holds the sensor stage, the schedule and the overpressure state, and
says what the diagnostics report. The physics are in valve_sim.core (faults,
sensors); valve_node only calls this.

A schedule file set live is opened (not read) by the parameter check, so a missing
file, a FIFO, a device or one beyond the size limit is refused at once; ScheduleLoader
then reads and checks it on a thread of its own, never on the tick's, and the tick
takes the checked events when they are ready (the file is read once: what was
checked is what is applied).
"""

from concurrent.futures import ThreadPoolExecutor
import json
import os
from pathlib import Path
import subprocess
import sys
import threading

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from valve_sim.core.catalogue import FAULT_SCHEDULE_SPEC, split
from valve_sim.core.errors import InputFileError
from valve_sim.core.fault_schedule import (
    event_from_line,
    load_schedule,
    open_schedule,
    Schedule,
)
from valve_sim.core.faults import at_supply_limit, FAULT_SPECS, HEALTHY
from valve_sim.core.model import P_C, P_S
from valve_sim.core.sensors import (
    checked_settings,
    default_settings,
    SENSOR_SPECS,
    SensorStage,
)
from valve_sim.ros.ros_parameters import declare


# The catalogue's entries of fault injection, in the order declared: doubles, switches, the
# noise seed, the schedule file.
KIND_ORDER = ('double', 'bool', 'integer', 'string')
INJECTION_SPECS = sorted(
    (*FAULT_SPECS.values(), *SENSOR_SPECS.values(), FAULT_SCHEDULE_SPEC),
    key=lambda spec: KIND_ORDER.index(spec.kind),
)
FAULT_STATUS_TOPIC = 'fault_status'
# Latched: a late subscriber (the analyser, a bench's monitor) gets the settings in effect.
FAULT_STATUS_QOS = QoSProfile(
    depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
PACKAGE_ROOT = str(Path(__file__).resolve().parents[2])  # the folder holding valve_sim


def declare_fault_parameters(node):
    """
    Declare fault.*, sensor.* and fault_schedule on node, as the catalogue has them.

    Returns (FaultSet, sensor settings, schedule path); raises ParameterError for bad values.
    """
    change = split({spec.name: declare(node, spec) for spec in INJECTION_SPECS})
    faults = HEALTHY.changed(change.fault)
    sensors = checked_settings(default_settings(), change.sensor)
    return faults, sensors, change.schedule[FAULT_SCHEDULE_SPEC.name]


class FaultInjection:
    """
    The node's sensor stage, fault schedule and overpressure state.

    sensor_settings: checked sensor settings; schedule_path: a schedule file or ''.
    Raises InputFileError or ParameterError for a bad schedule.
    """

    def __init__(self, sensor_settings, schedule_path=''):
        self.sensors = SensorStage(sensor_settings)
        self.schedule = Schedule()
        self.schedule_path = ''
        self.origin_ns = None  # model time of the tick the schedule counts from [ns]
        self.overpressure = False
        self.use_schedule(schedule_path)

    def use_schedule(self, path):
        """Load a schedule file ('' for none) now; its t counts from the next tick."""
        self.use_events(load_schedule(path) if path else (), path)

    def use_events(self, events, path):
        """Use the checked events of the schedule file path; their t counts from the next tick."""
        self.schedule = Schedule(events)
        self.schedule_path = path
        self.origin_ns = None

    def rebase(self, shift_ns):
        """Move what is timed by shift_ns [ns]: the clock jumped (a new time base)."""
        if self.origin_ns is not None:
            self.origin_ns += shift_ns
        self.sensors.rebase(shift_ns)

    def due(self, time_ns):
        """Return the schedule's {name: value} changes due at the tick at time_ns [ns]."""
        if self.origin_ns is None:
            self.origin_ns = time_ns
        return self.schedule.due(time_ns - self.origin_ns) if self.schedule.pending() else {}

    def readings(self, time_ns, state, ambient_pressure):
        """Return the published pressures [Pa absolute] of a state; nan: nothing published."""
        return self.sensors.read(time_ns, [p + ambient_pressure for p in state[P_S:P_C + 1]])

    def at_supply_limit(self, state, limit):
        """Return whether p_s [Pa gauge] of state has reached the supply's limit [Pa]."""
        return at_supply_limit(state[P_S], limit)

    def status_message(self, faults, stamp, name, hardware_id):
        """
        Return the fault_status DiagnosticArray: every fault and sensor setting in effect.

        stamp: builtin_interfaces Time from which they hold; name: the status name
        ('<node name>: faults', as diagnostics.status_name gives it); hardware_id: the
        node's. Level WARN while any is active; the message names the active ones.
        """
        active = [faults.describe()] * bool(faults.active()) + self.sensors.describe_faults()
        settings = {**faults.as_parameters(), **self.sensors.settings}
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if active else DiagnosticStatus.OK,
            name=name,
            hardware_id=hardware_id,
            message=', '.join(active) or 'healthy valve, ideal sensors',
            values=[
                KeyValue(key=key, value=_text(value)) for key, value in settings.items()
            ],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = stamp
        return array

    def conditions(self, faults, supply_pressure, limit):
        """
        Return [(level, text)] for the diagnostics: overpressure, faults, sensor faults.

        The overpressure alarm (ERROR) names the faults that drove p_s to the limit.
        """
        conditions = []
        named = faults.describe()
        if self.overpressure:
            conditions.append(
                (
                    DiagnosticStatus.ERROR,
                    f'OVERPRESSURE: p_s = {supply_pressure:.6g} Pa at supply_pressure_limit '
                    f'= {limit:g} Pa (the supply relieves the inflow); '
                    + (f'faults: {named}' if named else 'no valve fault active'),
                )
            )
        if named:
            conditions.append((DiagnosticStatus.WARN, f'faults active: {named}'))
        sensors = self.sensors.describe_faults()
        if sensors:
            dropped = self.sensors.dropped_topics()
            text = f'sensor settings: {", ".join(sensors)}'
            if dropped:
                text += f'; dropout: nothing published on {", ".join(dropped)}'
            conditions.append((DiagnosticStatus.WARN, text))
        return conditions


class ScheduleLoader:
    """
    Reads and checks fault schedule files in a process of their own, one at a time.

    opened(path) opens the file (InputFileError at once for one that cannot be a
    schedule); start() hands it to a child process (python -m
    valve_sim.core.fault_schedule), which reads, parses and checks it, and a thread of
    the loader takes its events line by line; take() returns, once, the result:
    (path, events) or (path, the error's text), else None while it runs. Parsing in
    the node's own interpreter, even on another thread, held the tick up to 160 ms
    (C parsing and garbage collection hold the GIL).
    """

    TIMEOUT = 60.0  # [s] a check that takes longer is stopped and refused

    def __init__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix='fault_schedule')
        self.loading = ''  # the path being read, '' when none
        self._future = None

    def opened(self, path):
        """Open path as a schedule (not read yet); raises InputFileError."""
        return open_schedule(path)

    def start(self, path, stream):
        """Read and check the opened schedule path in a child process."""
        self.loading = path
        self._future = self._pool.submit(self._load, path, stream)

    def take(self):
        """Return (path, events or error text) of a finished load, once; else None."""
        if self._future is None or not self._future.done():
            return None
        future, path, self._future, self.loading = self._future, self.loading, None, ''
        error = future.exception()
        return (path, future.result()) if error is None else (path, str(error))

    def close(self):
        self._pool.shutdown(wait=False, cancel_futures=True)

    def _load(self, path, stream):
        """Run the check in a child process; return the events or raise with its message."""
        with stream:
            descriptor = stream.fileno()
            process = subprocess.Popen(
                [sys.executable, '-m', 'valve_sim.core.fault_schedule', str(descriptor), path],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                pass_fds=(descriptor,),
                env={**os.environ, 'PYTHONPATH': os.pathsep.join(filter(None, (
                    PACKAGE_ROOT, os.environ.get('PYTHONPATH')
                )))},
            )
        watchdog = threading.Timer(self.TIMEOUT, process.kill)
        watchdog.start()
        try:
            with process.stdout:
                outcome = json.loads(process.stdout.readline() or '{}')
                if 'events' not in outcome:
                    raise InputFileError(outcome.get('error') or (
                        f'fault schedule {path}: the check ended without an answer (stopped '
                        f'after {self.TIMEOUT:g} s, or out of memory)'
                    ))
                events = [event_from_line(line) for line in process.stdout]
        finally:
            watchdog.cancel()
            process.kill()
            process.wait()
        if len(events) != outcome['events']:
            raise InputFileError(f'fault schedule {path}: the check ended early')
        return events


def _text(value):
    """Format a setting as diagnostics text: true/false, or the number in full precision."""
    return str(value).lower() if isinstance(value, bool) else repr(value)
