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

"""valve_node's inlet-flow input: every message counted, the last good value kept."""

import math

from rclpy.serialization import serialize_message
from std_msgs.msg import Float64
from valve_sim.ros.inlet_input import InletFlowInput


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
