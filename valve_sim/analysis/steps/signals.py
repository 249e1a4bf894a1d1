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
The signals of a step test in recorded messages, sampled on one time axis.

Six roles, each carried by a topic (valve_node's by default, any other by mapping):

  role            default topic        supported types (value taken)
  supply_pressure supply_pressure      sensor_msgs/msg/FluidPressure (fluid_pressure),
                                       std_msgs/msg/Float64 (data)
  main_valve      joint_states         sensor_msgs/msg/JointState (position of joint main_valve),
                                       Float64 (data)
  pilot_poppet    joint_states         JointState (position of joint pilot_poppet),
                                       Float64 (data); optional
  inlet_flow      applied_inlet_flow   JointState (velocity of joint inlet_flow), Float64 (data)
  tank_pressure   applied_tank_pressure  FluidPressure (fluid_pressure), Float64 (data);
                                       optional
  relief_flow     relief_flow          JointState (velocity of joint relief_flow), Float64
                                       (data); optional

Pressures on the wire are absolute [Pa]; ambient_pressure [Pa] is subtracted to get
the model's gauge pressure (0 for a gauge sensor). Displacements [m], flows [m^3/s].
Where the tank's pressure is known, the step measures take the supply pressure above
it, p_s - p_t (valve_sim.analysis.steps.step_analysis).

Time: clock "header" takes header.stamp (valve_node stamps every message of a tick
with the model time); clock "receive" takes each message's receive time (the bag's
log_time), which std_msgs/msg/Float64 needs since it has no header.

Joining: every supply-pressure sample is one row; each other role contributes its
latest value at or before that time (Joiner), and the row keeps that sample's time
(row['times'][role], ns): a step of a flow sampled more coarsely than the pressure
lies between two flow samples, which the step analysis needs. With valve_node all
stamps of a tick are equal, so this is an exact join. The live analyser and bag analysis share this
code, so both see the same rows.
"""

from collections import deque
from dataclasses import dataclass, field
import math

from valve_sim.core.errors import InputFileError
from valve_sim.core.parameters import STANDARD_ATMOSPHERE


FLUID_PRESSURE = 'sensor_msgs/msg/FluidPressure'
JOINT_STATE = 'sensor_msgs/msg/JointState'
FLOAT64 = 'std_msgs/msg/Float64'
CLOCKS = ('header', 'receive')
MAX_PENDING_ROWS = (
    10_000  # rows waiting for a silent role before the oldest are dropped (10 s at 1 kHz)
)


@dataclass(frozen=True)
class Role:
    """One signal: name, default topic (relative), default joint and JointState field, meaning."""

    name: str
    topic: str
    joint: str
    joint_field: str
    meaning: str


ROLES = (
    Role(
        'supply_pressure',
        'supply_pressure',
        '',
        '',
        'supply pressure p_s [Pa, absolute on the wire]',
    ),
    Role('main_valve', 'joint_states', 'main_valve', 'position', 'main-valve displacement x [m]'),
    Role(
        'pilot_poppet',
        'joint_states',
        'pilot_poppet',
        'position',
        'pilot-poppet displacement y [m]',
    ),
    Role(
        'inlet_flow',
        'applied_inlet_flow',
        'inlet_flow',
        'velocity',
        'applied inlet flow q_in [m^3/s]',
    ),
    Role(
        'tank_pressure',
        'applied_tank_pressure',
        '',
        '',
        'tank pressure p_t [Pa, absolute on the wire]',
    ),
    Role('relief_flow', 'relief_flow', 'relief_flow', 'velocity', 'relief flow q_r [m^3/s]'),
)
ROLE = {role.name: role for role in ROLES}
REQUIRED = ('supply_pressure', 'main_valve', 'inlet_flow')  # what the measures need
PRESSURES = ('supply_pressure', 'tank_pressure')  # absolute on the wire
TYPES = dict.fromkeys(PRESSURES, (FLUID_PRESSURE, FLOAT64))  # others: JOINT_STATE or FLOAT64


@dataclass
class SignalMap:
    """Where each role is found: topics and joint names by role, ambient pressure [Pa], clock."""

    topics: dict = field(default_factory=lambda: {role.name: '/' + role.topic for role in ROLES})
    joints: dict = field(
        default_factory=lambda: {role.name: role.joint for role in ROLES if role.joint}
    )
    ambient_pressure: float = STANDARD_ATMOSPHERE
    clock: str = 'header'

    def roles_of(self, topic):
        """Role names carried by a topic."""
        return [name for name, mapped in self.topics.items() if mapped == topic]

    def valve_namespace(self):
        """Return valve_node's namespace ('' or '/rig1'): that of the supply-pressure topic."""
        return self.topics['supply_pressure'].rsplit('/', 1)[0]


def stamp_ns(stamp):
    """Integer nanoseconds of a builtin_interfaces/Time."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def seconds(time_ns):
    """
    Seconds [s] of integer nanoseconds: the time axis of every analysis.

    int / int is correctly rounded (1700000000250000000 ns -> 1700000000.25 s);
    time_ns / 1e9 would first round the integer to a float and miss by up to 128 ns.
    """
    return time_ns / 1_000_000_000


class Extractor:
    """Takes role values out of the messages of one topic of a given type."""

    def __init__(self, topic, type_name, roles, signal_map):
        for role in roles:
            allowed = TYPES.get(role, (JOINT_STATE, FLOAT64))
            if type_name not in allowed:
                raise InputFileError(
                    f'topic {topic} ({ROLE[role].meaning}) has type {type_name}; '
                    f'supported: {", ".join(allowed)}'
                )
        if signal_map.clock == 'header' and type_name == FLOAT64:
            raise InputFileError(
                f'topic {topic} is {FLOAT64}, which has no header stamp: use the receive clock'
            )
        self.topic, self.type_name, self.roles, self.map = topic, type_name, roles, signal_map
        self.non_finite = 0  # values left out: inf or NaN (a broken sensor, a corrupt file)

    def _value(self, role, message):
        if self.type_name == FLOAT64:
            value = message.data
        elif self.type_name == FLUID_PRESSURE:
            value = message.fluid_pressure
        else:
            joint = self.map.joints[role]
            try:
                value = getattr(message, ROLE[role].joint_field)[list(message.name).index(joint)]
            except (ValueError, IndexError):
                return None
        return value - self.map.ambient_pressure if role in PRESSURES else value

    def samples(self, message, receive_time_ns):
        """
        Return [(role, time_ns, value)] of one message.

        A JointState lacking the joint gives nothing for it; a value that is not finite
        gives nothing either, and is counted (non_finite).
        """
        time_ns = (
            receive_time_ns if self.map.clock == 'receive' else stamp_ns(message.header.stamp)
        )
        values = [(role, self._value(role, message)) for role in self.roles]
        finite = [(role, v) for role, v in values if v is not None and math.isfinite(v)]
        self.non_finite += sum(v is not None for _, v in values) - len(finite)
        return [(role, time_ns, value) for role, value in finite]


class Joiner:
    """
    Rows (time_ns, {role: value}) at the supply-pressure times, fed one sample at a time.

    A row is complete once every other role has a sample at or after its time
    (samples of each role arrive in time order); the role's value is then its
    latest sample at or before the row's time, and row['times'][role] that sample's
    time [ns]. Rows before a required role's first sample are dropped; an optional
    role without a sample there is None,
    and rows do not wait for an optional role that has not begun.
    """

    def __init__(self, required=REQUIRED, optional=()):
        self.required = set(required) - {'supply_pressure'}
        self.history = {role: deque() for role in self.required | set(optional)}
        self.pending = deque()
        self.dropped_rows = 0

    def add(self, role, time_ns, value):
        """Feed one sample; returns the rows it completes, in time order."""
        if role == 'supply_pressure':
            if self.pending and time_ns <= self.pending[-1][0]:
                self.pending.clear()  # time went back: what waits belongs to the past
            self.pending.append((time_ns, value))
            if len(self.pending) > MAX_PENDING_ROWS:
                self.pending.popleft()
                self.dropped_rows += 1
        elif role in self.history:
            history = self.history[role]
            if history and time_ns < history[-1][0]:
                history.clear()
            history.append((time_ns, value))
        return self._complete_rows(final=False)

    def finish(self):
        """Return the rows still waiting (end of the recording), from the samples there are."""
        return self._complete_rows(final=True)

    def _known_at(self, time_ns):
        """
        Return True when every role that counts has reached time_ns.

        The roles that count are every required role and every optional role that has begun.
        """
        return all(
            history[-1][0] >= time_ns if history else role not in self.required
            for role, history in self.history.items()
        )

    def _complete_rows(self, final):
        rows = []
        while self.pending:
            time_ns, pressure = self.pending[0]
            if not final and not self._known_at(time_ns):
                break
            self.pending.popleft()
            row, times = {'supply_pressure': pressure}, {'supply_pressure': time_ns}
            for role, history in self.history.items():
                while len(history) > 1 and history[1][0] <= time_ns:
                    history.popleft()
                known = history and history[0][0] <= time_ns
                row[role] = history[0][1] if known else None
                if known:
                    times[role] = history[0][0]
            row['times'] = times
            if all(row[role] is not None for role in self.required):
                rows.append((time_ns, row))
        return rows
