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

"""valve_node's inputs (inlet flow, tank pressure): every message counted, the last good kept."""

import math
import time

import pytest
from rclpy.serialization import serialize_message
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64
from valve_sim.ros.node_status import Throttle
from valve_sim.ros.valve_inputs import InletFlowInput, TankPressureInput


MAX_FLOW = 1.6666666666666667e-3  # [m^3/s] max_inlet_flow of config/reference.yaml


def cdr(value):
    return serialize_message(Float64(data=value))


def test_each_message_is_accepted_or_rejected_and_the_last_good_one_kept():
    received = InletFlowInput(1e-4, MAX_FLOW)
    values = [2e-4, math.nan, 1.0, 3e-4, -1e-9, math.inf, 0.0, 1e-15, MAX_FLOW * 1.000001]
    for value in values:
        received.offer_cdr(cdr(value))
    assert (received.accepted, received.rejected) == (4, 5)
    assert received.flow == 1e-15 and received.changed
    assert 'exceeds max_inlet_flow' in received.last_rejection
    assert received.report() == (5, received.last_rejection) and received.report()[0] == 0


def test_a_message_that_is_not_a_float64_is_rejected_not_raised():
    received = InletFlowInput(1e-4, MAX_FLOW)
    assert not received.offer_cdr(b'\x00\x01\x00\x00\x01')
    assert received.rejected == 1 and received.flow == 1e-4


def test_arrival_is_stamped_by_the_next_tick():
    received = InletFlowInput(1e-4, MAX_FLOW)
    received.offer_cdr(cdr(2e-4))
    received.stamp(5_000)
    received.stamp(9_000)
    assert received.received_ns == 5_000


class QueuedSubscription:
    """A raw subscription's handle as the node takes from it: messages with sequence numbers."""

    msg_type = Float64

    def __init__(self, values, sequences=None):
        sequences = sequences or range(1, len(values) + 1)
        self.queue = [
            (cdr(value), {'publication_sequence_number': sequence})
            for value, sequence in zip(values, sequences)
        ]
        self.handle = self

    def __enter__(self):
        return self

    def __exit__(self, *_):
        return False

    def take_message(self, message_type, raw):
        assert message_type is Float64 and raw
        return self.queue.pop(0) if self.queue else None


def test_a_tick_takes_a_bounded_number_of_messages_and_counts_each():
    received = InletFlowInput(1e-4, MAX_FLOW)
    queued = QueuedSubscription([2e-4, math.nan, 3e-4, 1.0, 4e-4])
    assert received.take(queued, 3, time.perf_counter_ns() + 10**9) == 3
    assert (received.accepted, received.rejected, received.flow) == (2, 1, 3e-4)
    assert received.take(queued, 3, time.perf_counter_ns() + 10**9) == 2
    assert (received.accepted, received.rejected, received.flow) == (3, 2, 4e-4)
    assert received.take(queued, 3, time.perf_counter_ns() + 10**9) == 0


def test_no_message_is_taken_after_the_deadline():
    received = InletFlowInput(1e-4, MAX_FLOW)
    queued = QueuedSubscription([2e-4])
    assert received.take(queued, 10, time.perf_counter_ns() - 1) == 0
    assert len(queued.queue) == 1 and received.accepted == 0


def test_outside_a_tick_the_node_takes_its_inputs_whatever_the_time():
    """
    A paused clock's housekeeping and a reset take the flow sent to them: no tick deadline.

    In a tick, a share of the period that passed before the first take leaves the message
    for the next tick; outside a tick there is no next tick to leave it to (stress run of
    2026-12-06: a flow sent to a paused clock was not taken for 60 s).
    """
    from types import SimpleNamespace

    from valve_sim.ros.valve_node import ReliefValveNode

    node = SimpleNamespace(
        input=InletFlowInput(1e-4, MAX_FLOW),
        tank_input=TankPressureInput(AMBIENT, BURST),
        inlet_subscription=QueuedSubscription([2e-4]),
        tank_subscription=QueuedSubscription([]),
        _tick_timer=SimpleNamespace(timer_period_ns=1_000_000),
    )
    ReliefValveNode.take_inputs(node, time.perf_counter_ns() - 10**9)  # a tick, its share past
    assert node.input.accepted == 0
    ReliefValveNode.take_inputs(node)  # the housekeeping's and the reset's call
    assert (node.input.accepted, node.input.flow) == (1, 2e-4)


def test_messages_a_single_publisher_sent_that_never_came_are_counted_lost():
    received = InletFlowInput(1e-4, MAX_FLOW)
    received.take(QueuedSubscription([2e-4, 3e-4], [1, 2]), 10, time.perf_counter_ns() + 10**9)
    received.single_publisher = True
    received.take(QueuedSubscription([2e-4, 3e-4], [5, 9]), 10, time.perf_counter_ns() + 10**9)
    assert received.lost == 2 + 3
    received.take(QueuedSubscription([2e-4], [1]), 10, time.perf_counter_ns() + 10**9)
    assert received.lost == 5, 'a restarted publisher counts from 1 again: nothing lost'
    received.single_publisher = False  # two publishers: their sequences interleave
    received.take(QueuedSubscription([2e-4, 3e-4], [7, 3]), 10, time.perf_counter_ns() + 10**9)
    assert received.lost == 5


def test_a_throttle_lets_one_event_through_per_interval_of_the_steady_clock():
    throttle = Throttle(1_000_000_000)
    assert throttle.due(5_000_000_000)
    assert not throttle.due(5_000_000_001) and not throttle.due(5_999_999_999)
    assert throttle.due(6_000_000_000) and not throttle.due(6_500_000_000)


AMBIENT = 101325.0  # [Pa] ambient_pressure of config/reference.yaml
BURST = 35.0e6  # [Pa, gauge] burst_pressure of config/reference.yaml


def fluid_pressure(absolute, frame_id='tank_port'):
    message = FluidPressure(fluid_pressure=absolute, variance=0.0)
    message.header.frame_id = frame_id
    return serialize_message(message)


@pytest.mark.parametrize('frame_id', ['', 'a', 'tank', 'rig/tank_port'])
def test_a_tank_pressure_is_read_whatever_the_length_of_its_frame_id(frame_id):
    received = TankPressureInput(AMBIENT, BURST)
    assert received.gauge() is None, 'no tank pressure before the first message'
    assert received.offer_cdr(fluid_pressure(AMBIENT + 3e5, frame_id))
    assert received.value == AMBIENT + 3e5 and received.gauge() == pytest.approx(3e5)


def test_bad_tank_pressures_are_refused_counted_and_never_held():
    """NaN, infinities, below vacuum (absolute < 0), at or beyond burst: refused."""
    received = TankPressureInput(AMBIENT, BURST)
    received.offer_cdr(fluid_pressure(AMBIENT + 2e5))
    bad = [math.nan, math.inf, -math.inf, -1.0, -1e5, AMBIENT + BURST, 1e300]
    for value in bad:
        assert not received.offer_cdr(fluid_pressure(value)), value
    assert (received.accepted, received.rejected) == (1, len(bad))
    assert received.gauge() == pytest.approx(2e5), 'the last good value is held'
    assert 'burst_pressure' in received.last_rejection
    assert not received.offer_cdr(b'\x00\x01\x00\x00' + bytes(8)), 'too short for a FluidPressure'
    assert received.rejected == len(bad) + 1 and 'FluidPressure' in received.last_rejection


def test_vacuum_is_judged_with_the_ambient_pressure_in_use():
    received = TankPressureInput(AMBIENT, BURST)
    assert received.offer_cdr(fluid_pressure(0.0)), 'absolute 0 is a (hard) vacuum, not below'
    received.ambient_pressure = 2e5  # a node at altitude set otherwise: the gauge moves
    assert received.gauge() == -2e5


def test_lockstep_inputs_apply_the_value_stamped_for_the_tick_once_a_later_stamp_came():
    """Issue 42: a value holds from its stamp; a tick waits for a later stamp; the later wins."""
    flow = InletFlowInput(1e-4, 1e-3)
    flow.lockstep()
    assert not flow.covers(100)
    flow.offer_at(100, 2e-4)  # the value for the tick from 100 on
    assert not flow.covers(100)  # another value for 100 may still come
    flow.offer_at(100, 3e-4)  # ... and does: sent later, it holds
    flow.offer_at(130, 5e-3)  # above max_inlet_flow: refused, but it covers 100 to 129
    assert flow.covers(100) and flow.covers(129) and not flow.covers(130)
    assert (flow.accepted, flow.rejected) == (2, 1) and 'max_inlet_flow' in flow.last_rejection
    flow.hold_at(110)
    assert flow.flow == 3e-4 and flow.changed
    flow.hold_at(130)
    assert flow.flow == 3e-4  # the refused value never holds
    flow.receive(b'\x00\x01\x00\x00' + bytes(8), {})  # a plain Float64 in lockstep: refused
    assert flow.rejected == 2 and 'inlet_flow_stamped' in flow.last_rejection
