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
valve_node's inputs: every message taken is counted, the last good one kept.

The node takes the input messages itself, at the start of each tick, from
subscriptions no executor runs (ReliefValveNode.subscriptions leaves them out): a flood
never wakes the executor, so it cannot queue callbacks ahead of the tick timer.
take() reads at most a few queued messages per tick, and none after its deadline:
each take locks the middleware's reader, which a flood keeps busy, so the tick
bounds how often it waits for that lock. Each message is checked as CDR bytes (the
double read from them, no message object) against the physical limits
(valve_sim.core.limits) and counted as accepted or rejected; only the last good
value matters to the tick. What the middleware dropped before the node took it
shows, for a single publisher, as gaps in its publication sequence numbers (lost),
counted by the raw taker both nodes share (valve_sim.ros.raw_take).
Nothing is logged per message: report() gives the rejections since the last report,
for one rate-limited warning.

CheckedInput is that taking, checking and counting, once; InletFlowInput (std_msgs/Float64,
m^3/s) and TankPressureInput (sensor_msgs/FluidPressure, absolute Pa) say only how their
message is read and which values are valid. Both subscriptions' QoS (INLET_FLOW_QOS, the
inlet_flow_reliability parameter) and how much a tick takes (INPUTS_PER_TICK, INPUT_SHARE)
live here too.

Lockstep inputs (lockstep()): each message carries the model time it applies from as
its header stamp (the flow on inlet_flow_stamped, the tank pressure on tank_pressure);
a value checked and counted when taken is scheduled, and the tick starting at t_k holds
the one stamped last at or before t_k (hold_at; of two at one stamp the later sent),
once a message stamped later than t_k has come (covers): ros.lockstep_inputs waits for
it, so /clock cannot race an input.
"""

import bisect
import itertools
import struct

from rclpy.qos import QoSProfile, ReliabilityPolicy
from valve_sim.core.limits import inlet_flow_problem, tank_pressure_problem
from valve_sim.recording.cdr import read_message, STAMP, STAMP_OFFSET
from valve_sim.ros.raw_take import RawTaker


# A tick takes at most INPUTS_PER_TICK inlet_flow messages, and none after INPUT_SHARE of
# its period: under a flood each take waits for the middleware's busy reader lock.
INPUTS_PER_TICK = 10
INPUT_SHARE = 0.2
RELIABLE_INPUT_DEPTH = 1000  # a 1 s burst at 1 kHz
# inlet_flow_reliability: best effort by default, as REP 2003 asks of sensor-data subscribers:
# it matches reliable and best-effort (SensorDataQoS) publishers alike (a reliable subscription
# never hears the latter). Its queue keeps the last INPUTS_PER_TICK messages, all that the next
# tick takes, so the value applied is never older than the tick; a flood beyond that is dropped
# by the middleware (counted as lost for a single publisher). Reliable keeps a burst for the
# ticks to take and count, at the price of up to RELIABLE_INPUT_DEPTH / INPUTS_PER_TICK ticks
# of delay while a reliable flood keeps it full (a deep full queue also costs the middleware
# more per message).
INLET_FLOW_QOS = {
    'best_effort': QoSProfile(depth=INPUTS_PER_TICK, reliability=ReliabilityPolicy.BEST_EFFORT),
    'reliable': QoSProfile(depth=RELIABLE_INPUT_DEPTH, reliability=ReliabilityPolicy.RELIABLE),
}
RELIABILITY_DESCRIPTION = (
    "inlet_flow and tank_pressure subscriptions: 'best_effort' (default; hears "
    f'every publisher, keeps the last {INPUTS_PER_TICK} messages for the next '
    "tick) or 'reliable' (reliable publishers only; keeps a burst of "
    f'{RELIABLE_INPUT_DEPTH} for the ticks to take and count)'
)
FLOAT64_CDR = struct.Struct('<d')  # std_msgs/Float64 data after the 4-byte CDR header
CDR_HEADER = 4
STRING_LENGTH = struct.Struct('<I')
FRAME_ID_OFFSET = CDR_HEADER + 8  # std_msgs/Header: stamp (int32 sec, uint32 nanosec), frame_id
NS_PER_S = 1_000_000_000
STAMPED_FLOW_TOPIC = 'inlet_flow_stamped'  # lockstep: sensor_msgs/JointState, velocity[0]


class CheckedInput(RawTaker):
    """
    One input topic: the last good value and counts of what was received.

    value: the value held until a good message comes. accepted and rejected count
    every message offered, lost the messages a single publisher sent that never came
    (single_publisher, set by the node); changed is set by a good value that differs
    from the one held (cleared by the node when it used it). A subclass says how a
    message is read (decode) and which values are valid (problem).
    """

    def __init__(self, value):
        super().__init__()
        self.value = value
        self.accepted = 0
        self.rejected = 0
        self.changed = False
        self.received = False  # a good message came since the last stamp()
        self.received_ns = None  # clock time [ns] of the tick after the last good message
        self.last_rejection = ''
        self.reported_rejected = 0  # rejected at the last report()
        self.scheduled = None  # lockstep: [(stamp [ns], arrival, value)] in stamp order
        self.covered_ns = None  # lockstep: the latest stamp taken [ns]
        self._arrivals = itertools.count()

    def lockstep(self):
        """Take stamped messages from now on: each value from its stamp on (hold_at)."""
        self.scheduled = []

    def restart(self, value):
        """Hold value as at start-up: every value received, its stamps and counts forgotten."""
        self.value, self.changed, self.received, self.received_ns = value, False, False, None
        self.covered_ns = None
        self.accepted = self.rejected = self.reported_rejected = self.lost = 0
        self.last_rejection = ''
        if self.scheduled is not None:
            self.scheduled = []

    def problem(self, value):
        """Return why value is not a valid input, or None."""
        raise NotImplementedError

    def decode(self, data):
        """Return the value of a serialized message, or None if the bytes are not one."""
        raise NotImplementedError

    def offer(self, value):
        """Take a received value: keep it if it is valid, count it either way."""
        if self._check(value):
            self._hold(value)
            return True
        return False

    def _check(self, value):
        """Count value as accepted or rejected (with its reason); return whether it is valid."""
        problem = self.problem(value)
        if problem is None:
            self.accepted += 1
            return True
        self._reject(problem)
        return False

    def _reject(self, reason):
        self.rejected += 1
        self.last_rejection = reason

    def _hold(self, value):
        self.changed = self.changed or value != self.value
        self.value = value
        self.received = True

    def offer_at(self, stamp_ns, value):
        """
        Lockstep: take value [SI] from model time stamp_ns [ns] on, checked and counted now.

        A rejected value still covers its stamp: the tick does not wait for it, and holds
        the value before it (which the driver sees in the tick's applied value).
        """
        self.covered_ns = stamp_ns if self.covered_ns is None else max(self.covered_ns, stamp_ns)
        if self._check(value):
            bisect.insort(self.scheduled, (stamp_ns, next(self._arrivals), value))

    def covers(self, time_ns):
        """Lockstep: whether a message stamped later than time_ns [ns] has been taken."""
        return self.covered_ns is not None and self.covered_ns > time_ns

    def hold_at(self, time_ns):
        """Lockstep: hold the value stamped last at or before time_ns [ns] (the last sent)."""
        index = bisect.bisect_right(self.scheduled, (time_ns, float('inf')))
        if index:
            self._hold(self.scheduled[index - 1][2])
            del self.scheduled[:index]

    def offer_cdr(self, data):
        """Take a serialized message (little-endian CDR, as ROS 2 sends it)."""
        value = self.decode(data) if len(data) > CDR_HEADER and data[1] == 1 else None
        if value is None:
            self.rejected += 1
            self.last_rejection = f'not a little-endian {self.MESSAGE_TYPE} ({len(data)} bytes)'
            return False
        return self.offer(value)

    def receive(self, data, info):
        """Take a message as RawTaker.take() hands it over: its CDR bytes are checked."""
        if self.scheduled is None:
            self.offer_cdr(data)
            return
        stamped = self.decode_stamped(data) if len(data) > CDR_HEADER and data[1] == 1 else None
        if stamped is None:
            self._reject(f'a lockstep input needs a stamped {self.STAMPED_TYPE}')
        else:
            self.offer_at(*stamped)

    def decode_stamped(self, data):
        """Lockstep: return (stamp [ns], value) of a stamped message, or None."""
        return None

    def stamp(self, now_ns):
        """At a tick: a good message received since the last tick arrived by now_ns [ns]."""
        if self.received:
            self.received = False
            self.received_ns = now_ns

    def rebase(self, shift_ns):
        """Move received_ns by shift_ns [ns]: the clock jumped (a new time base)."""
        if self.received_ns is not None:
            self.received_ns += shift_ns

    def report(self):
        """Return (rejections since the last report, the last reason) and start a new count."""
        new = self.rejected - self.reported_rejected
        self.reported_rejected = self.rejected
        return new, self.last_rejection


class InletFlowInput(CheckedInput):
    """
    The inlet flow [m^3/s] from std_msgs/Float64: 0 to max_inlet_flow [m^3/s].

    flow: the flow held until a good message comes.
    """

    MESSAGE_TYPE = 'std_msgs/Float64'
    STAMPED_TYPE = 'sensor_msgs/JointState on ' + STAMPED_FLOW_TOPIC

    def __init__(self, flow, max_inlet_flow):
        super().__init__(flow)
        self.max_inlet_flow = max_inlet_flow

    @property
    def flow(self):
        """Return the inlet flow held [m^3/s]."""
        return self.value

    def problem(self, value):
        """Return why value is not a valid inlet flow [m^3/s], or None."""
        return inlet_flow_problem(value, self.max_inlet_flow)

    def decode(self, data):
        """Return the data of a std_msgs/Float64, or None if too short."""
        if len(data) < CDR_HEADER + FLOAT64_CDR.size:
            return None
        return FLOAT64_CDR.unpack_from(data, CDR_HEADER)[0]

    def receive_stamped(self, data, info):
        """Take a message of inlet_flow_stamped (a RawTaker's receive): velocity[0], stamped."""
        try:
            message = read_message('sensor_msgs/msg/JointState', data)
        except (ValueError, struct.error):
            message = None
        if message is None or len(message.velocity) != 1:
            self._reject(f'not a {self.STAMPED_TYPE} with one velocity ({len(data)} bytes)')
            return
        stamp = message.header.stamp
        self.offer_at(stamp.sec * NS_PER_S + stamp.nanosec, message.velocity[0])


class TankPressureInput(CheckedInput):
    """
    The tank's pressure from sensor_msgs/FluidPressure: absolute [Pa], as the message defines it.

    value: the last good absolute pressure, None until one came; gauge(): it less
    ambient_pressure [Pa], the model's tank pressure. Valid: finite, not below vacuum,
    and below burst_pressure [Pa, gauge] (limits.tank_pressure_problem); both limits
    are the node's, set again when they change.
    """

    MESSAGE_TYPE = 'sensor_msgs/FluidPressure'
    STAMPED_TYPE = MESSAGE_TYPE

    def __init__(self, ambient_pressure, burst_pressure):
        super().__init__(None)
        self.ambient_pressure = ambient_pressure
        self.burst_pressure = burst_pressure

    def gauge(self):
        """Return the tank pressure held [Pa, gauge], or None before the first good message."""
        return None if self.value is None else self.value - self.ambient_pressure

    def problem(self, value):
        """Return why value [Pa, absolute] is not a valid tank pressure, or None."""
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = value - self.ambient_pressure
        return tank_pressure_problem(value, self.burst_pressure, self.ambient_pressure)

    def decode(self, data):
        """fluid_pressure of a FluidPressure: after the header's stamp and frame_id, 8-aligned."""
        if len(data) < FRAME_ID_OFFSET + STRING_LENGTH.size:
            return None
        end = FRAME_ID_OFFSET + STRING_LENGTH.size + STRING_LENGTH.unpack_from(
            data, FRAME_ID_OFFSET
        )[0]
        offset = end + (-(end - CDR_HEADER) % FLOAT64_CDR.size)
        if offset + 2 * FLOAT64_CDR.size > len(data):
            return None
        return FLOAT64_CDR.unpack_from(data, offset)[0]

    def decode_stamped(self, data):
        """Lockstep: (header stamp [ns], fluid_pressure [Pa absolute]), or None."""
        value = self.decode(data)
        if value is None:
            return None
        sec, nanosec = STAMP.unpack_from(data, STAMP_OFFSET)
        return sec * NS_PER_S + nanosec, value
