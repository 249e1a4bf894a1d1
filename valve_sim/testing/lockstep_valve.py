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
A valve_node in lockstep for a test: advance it, set its flow and parameters, read it back.

LockstepValve starts valve_node on use_sim_time in a process of its own (its log in
folder/valve_node.log) and drives its /clock from the calling thread with
valve_sim.ros.lockstep.Lockstep, as `valve-sim scenario run` does: advance(seconds)
steps /clock up to TICKS_PER_CLOCK ticks at a time (ros.clock_jumps) and returns once
the valve's state of that time has arrived, every state of the way kept. Flows and
parameter changes act from the next tick, so a test repeats exactly.
Values are SI, or text with a unit ('20 L/min', '21 MPa'); parameters by ROS name or
paper symbol. Pressures read back are gauge [Pa], as the model's (tick_series).

Isolation: one open kit per process (a second is refused: both would share /clock and
the valve's topics); the kit runs in the environment's ROS_DOMAIN_ID unless another
process holds it (another pytest-xdist worker, another test run), then in a free one it
claims (valve_sim.ros.isolation.hold_domain, set in os.environ): a node of the test
that talks to the valve (a controller under test) must be created after the valve,
in the same process. Arguments are checked at the call (ValueError, TypeError, one
line); any call after close() raises RuntimeError; a start valve_node refuses raises
ChildProcessError with the node's reason, and keeps its log.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
import math
import os
from pathlib import Path
import shutil
import tempfile
import time
from typing import Any, Optional, Union

from valve_sim.analysis.scenarios.bench_scenario import live_change, start_parameter
from valve_sim.analysis.scenarios.tick_series import SIGNALS, TickSeries
from valve_sim.analysis.steps.input_events import SettingChanges
from valve_sim.core.errors import (
    InputFileError,
    NodeExitError,
    ParameterError,
    ProfileError,
    UnavailableError,
    ValveSimError,
    WrongTypeError,
)
from valve_sim.core.faults import PREFIX as FAULT_PREFIX
from valve_sim.core.limits import inlet_flow_problem
from valve_sim.core.output_files import make_folder
from valve_sim.core.parameters import STANDARD_ATMOSPHERE
from valve_sim.core.quantities import FLOW, parse_quantity
from valve_sim.recording.tick_bags import state_values
from valve_sim.recording.valve_topics import message_class, TICK_TOPICS, TOPIC_TYPES
from valve_sim.ros import node_command
from valve_sim.ros.clock_jumps import TICKS_PER_CLOCK
from valve_sim.ros.isolation import hold_domain
from valve_sim.ros.lockstep import Lockstep, lockstep_parameters, NS_PER_S, START_NS
from valve_sim.ros.node_processes import NodeProcesses
from valve_sim.ros.scenario_runner import ros_value


START_TIMEOUT = 180.0  # [s] valve_node's start-up (a cold kernel compile) and discovery
STRAGGLER_WAIT = 0.5  # [s] for a tick's other topics after its handshake
PathLike = Union[str, 'os.PathLike[str]']
# The states a kit keeps at most: about 0.8 kB each in memory (a dict of the 11 signals by
# stamp, measured with tracemalloc), so 600 000 (10 min of model time at 1 kHz) is 0.5 GB.
MAX_STATES = 600_000
LOG_LINES = 5  # of valve_node's log in the error of a refused start
_open_kit = []  # the kit open in this process, if any


class NoStepError(ValveSimError, LookupError):
    """The run has no step at the time asked for."""


def start_values(parameters, initial_flow):
    """Return ({ROS name: value} of parameters, the initial flow [m^3/s]); ValueError if wrong."""
    try:
        start = dict(start_parameter(name, value, name)
                     for name, value in (parameters or {}).items())
        return start, parse_quantity(initial_flow, FLOW)
    except (ProfileError, ValueError) as error:
        raise ParameterError(f'lockstep valve: {error}') from None


class LockstepValve:
    """
    valve_node on /clock, advanced by the test; every state kept.

    parameters: {name: value} valve_node starts with (ROS name or paper symbol, SI or
    with a unit); initial_flow: the inlet flow it starts at the steady state of;
    params_file: its --params-file; namespace: the valve's; folder: where its log goes
    (default: a temporary folder). Call close() (or use lockstep_valve()) to stop it.
    """

    def __init__(self, parameters: Optional[Mapping[str, Any]] = None,
                 initial_flow: Union[float, str] = '5 L/min',
                 params_file: Optional[PathLike] = None, namespace: str = '',
                 folder: Optional[PathLike] = None) -> None:
        import rclpy

        if _open_kit:
            raise UnavailableError(
                f'a lockstep valve is already open in this process (log in '
                f'{_open_kit[0].folder}): close it first; two would share /clock and the '
                "valve's topics")
        start, flow = start_values(parameters, initial_flow)
        self.ambient_pressure = float(start.get('ambient_pressure', STANDARD_ATMOSPHERE))
        self.namespace = namespace
        self._temporary = None if folder else tempfile.mkdtemp(prefix='valve_')
        self.folder = make_folder(Path(folder or self._temporary))
        self.domain = hold_domain()
        ros_args = ['--params-file', str(params_file)] if params_file else []
        if namespace:
            ros_args += ['-r', f'__ns:={namespace}']
        values = {**lockstep_parameters(), 'initial_inlet_flow': repr(flow),
                  **{name: ros_value(value) for name, value in start.items()}}
        self.processes = NodeProcesses(self.folder, {
            'valve_node': node_command('valve_node', parameters=values, ros_args=ros_args)})
        self._rows, self._latest, self._events = {}, {}, []
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self._driver = None
        _open_kit.append(self)
        try:
            self._begin(flow)
        except ChildProcessError as error:
            self._fail_start(error)
        except BaseException:
            self.close()
            raise

    def _begin(self, flow):
        """Connect a new driver to valve_node and take its first state, at flow's steady state."""
        self._driver = Lockstep(self.context, self.namespace, self.processes,
                                on_state=self._on_state, record_topics=TICK_TOPICS)
        self._driver.connect(timeout=START_TIMEOUT)
        self._first_state(flow)

    def _first_state(self, flow):
        """Take the connected driver's first state, at flow's steady state; no state kept."""
        self._rows, self._latest, self._events = {}, {}, []
        self.max_inlet_flow = self._driver.get_parameters(['max_inlet_flow'])['max_inlet_flow']
        self._driver.set_flow(flow)
        self._driver.start(START_NS)
        self._await_row(START_NS)

    def restart(self, parameters: Optional[Mapping[str, Any]] = None,
                initial_flow: Union[float, str] = '5 L/min') -> None:
        """
        Bring the valve back to a fresh start, in the same valve_node (its ~/restart).

        As a new LockstepValve(parameters, initial_flow) with this one's params_file and
        namespace: every parameter at its start-up value with parameters over it, no
        fault, the sensors, preset and tank as those say, the exact steady state of
        initial_flow, time from 0 again, no state kept. ValueError for a value the node
        refuses (then nothing changed).
        """
        driver = self._live()
        start, flow = start_values(parameters, initial_flow)
        driver.restart({**start, 'initial_inlet_flow': flow}, START_TIMEOUT)
        self.ambient_pressure = float(start.get('ambient_pressure', STANDARD_ATMOSPHERE))
        self._first_state(flow)  # the same driver: its discovery holds

    def _fail_start(self, error):
        """valve_node ended while starting: raise its reason from its log, which is kept."""
        log = self.processes.log('valve_node')
        lines = [line.strip() for line in log.read_text(errors='replace').splitlines()
                 if line.strip()]
        reasons = [line for line in lines if 'ERROR' in line or 'rror' in line] or lines
        self._temporary = None  # the log stays for the user to read
        try:
            self.close()
        except ChildProcessError:
            pass  # the node's own end: its reason follows
        raise NodeExitError(
            f'valve_node refused to start: {" | ".join(reasons[-LOG_LINES:]) or error} '
            f'(log kept: {log})') from None

    def _live(self):
        """Return the driver; RuntimeError once close() was called."""
        if self._driver is None:
            raise UnavailableError('this lockstep valve is closed: start another one')
        return self._driver

    def _on_state(self, topic, data):
        from rclpy.serialization import deserialize_message

        message = deserialize_message(data, message_class(TOPIC_TYPES[topic]))
        stamp = message.header.stamp.sec * NS_PER_S + message.header.stamp.nanosec
        values = state_values(topic, message, self.ambient_pressure)
        self._rows.setdefault(stamp, {}).update(values)
        self._latest.update(values)

    @property
    def time(self) -> float:
        """Return the model time [s] since the first state (t = 0)."""
        return (self._live().time_ns - START_NS) / NS_PER_S

    @property
    def period(self) -> float:
        """Return the tick period [s] (valve_node's publish_rate)."""
        return self._live().period_ns / NS_PER_S

    def advance(self, seconds: float) -> float:
        """
        Run the valve on by seconds of model time (whole ticks); returns the new time [s].

        seconds: a finite number >= 0 [s]; the states kept stay within MAX_STATES.
        """
        driver = self._live()
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float)):
            raise WrongTypeError(f'advance: seconds must be a number [s], got {seconds!r}')
        if not math.isfinite(seconds) or seconds < 0:
            raise ParameterError(f'advance: seconds must be finite and >= 0 (time only goes '
                                 f'forward), got {seconds!r}')
        ticks = round(seconds / self.period)
        room = MAX_STATES - len(self._rows)
        if ticks > room:
            raise ParameterError(
                f'advance({seconds!r}): {ticks} more states would pass the {MAX_STATES} a kit '
                f'keeps (about 0.8 kB each); at most {room * self.period:g} s more')
        for done in range(0, ticks, TICKS_PER_CLOCK):  # a /clock step of several ticks
            driver.tick(min(TICKS_PER_CLOCK, ticks - done))
        self._await_row(driver.time_ns)
        return self.time

    def _await_row(self, time_ns):
        """
        Spin until every topic's message of the tick at time_ns has come (or STRAGGLER_WAIT).

        The handshake is the last topic published, but topics may arrive out of order;
        a pressure sensor in dropout publishes nothing, hence the bound.
        """
        deadline = time.monotonic() + STRAGGLER_WAIT
        while len(self._rows.get(time_ns, ())) < len(SIGNALS) and time.monotonic() < deadline:
            self._driver.executor.spin_once(timeout_sec=0.01)

    def set_flow(self, flow: Union[float, str]) -> None:
        """
        Set the inlet flow (m^3/s, or text with a unit) from the next tick on.

        ValueError at the call for a value valve_node would refuse: negative, not finite
        or above its max_inlet_flow.
        """
        driver = self._live()
        try:
            value = parse_quantity(flow, FLOW)
        except ValueError as error:
            raise ParameterError(f'set_flow: {error}') from None
        problem = inlet_flow_problem(value, self.max_inlet_flow)
        if problem:
            raise ParameterError(f'set_flow({flow!r}): {problem}')
        driver.set_flow(value)

    def set_parameters(self, changes: Optional[Mapping[str, Any]] = None, **named: Any) -> None:
        """
        Change valve_node's live parameters at once, from the next tick on.

        changes/named: {name: value}, by ROS name or paper symbol, SI or with a unit;
        fault.* and sensor.* settings too. ValueError if a value is wrong or the node
        refuses it.
        """
        driver = self._live()
        try:
            resolved = dict(live_change(name, value)
                            for name, value in {**(changes or {}), **named}.items())
        except (ParameterError, ProfileError, InputFileError) as error:
            raise ParameterError(str(error)) from None
        before = driver.get_parameters(list(resolved))
        driver.set_parameters(resolved)
        changed = SettingChanges(before).changed(resolved)  # that change the model
        if changed:  # a change ends a step's window (docs/measures.md)
            self._events.append((self.time + self.period, changed))
        if 'max_inlet_flow' in resolved:
            self.max_inlet_flow = float(resolved['max_inlet_flow'])

    def inject(self, fault: str, value: Any = True) -> None:
        """Switch a fault on (docs/faults.md): a name such as 'main_valve_stuck', and its value."""
        if not isinstance(fault, str):
            raise WrongTypeError(f"inject: fault must be a fault's name such as "
                                 f"'main_valve_stuck' (docs/faults.md), got {fault!r}")
        name = fault if fault.startswith(FAULT_PREFIX) else FAULT_PREFIX + fault
        self.set_parameters({name: value})

    def get_parameters(self, *names: str) -> dict[str, Any]:
        """Return valve_node's values of names (ROS names) as a dict; ValueError if one lacks."""
        return self._live().get_parameters(names)

    @property
    def state(self) -> dict[str, float]:
        """Return the latest state: {signal: value} of tick_series.SIGNALS (SI, gauge [Pa])."""
        self._live()
        return dict(self._latest)

    @property
    def series(self) -> TickSeries:
        """Return every state so far as a TickSeries (time [s] from the first state)."""
        self._live()
        return TickSeries.from_rows(self._rows, START_NS)

    def measures(self, at: Optional[float] = None) -> Any:
        """
        Return the analyser's step records of the run so far (docs/measures.md).

        at: the time [s] of one step; then that step's record, or NoStepError (a LookupError).
        """
        steps = self.series.steps(events=self._events)
        if at is None:
            return steps
        near = [step for step in steps if abs(step['t_step'] - at) <= 1.5 * self.period]
        if not near:
            found = ', '.join(f'{step["t_step"]:g} s' for step in steps) or 'none'
            raise NoStepError(f'no step at {at:g} s (steps at: {found})')
        return near[0]

    def close(self) -> None:
        """Stop valve_node (SIGINT) and the driver; ChildProcessError if the node failed."""
        if self in _open_kit:
            _open_kit.remove(self)
        try:
            if self._driver is not None:
                self._driver.close()
                self._driver = None
            self.context.try_shutdown()
        finally:
            try:
                self.processes.stop()
            finally:
                if self._temporary is not None:
                    shutil.rmtree(self._temporary, ignore_errors=True)
                    self._temporary = None


@contextmanager
def lockstep_valve(parameters: Optional[Mapping[str, Any]] = None,
                   initial_flow: Union[float, str] = '5 L/min',
                   params_file: Optional[PathLike] = None, namespace: str = '',
                   folder: Optional[PathLike] = None) -> Iterator[LockstepValve]:
    """Start a LockstepValve for a with block; stop it after (see LockstepValve)."""
    valve = LockstepValve(parameters, initial_flow, params_file, namespace, folder)
    try:
        yield valve
    finally:
        valve.close()
