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
valve_node's inlet-flow input: every received message counted, the last good one kept.

The subscription callback only calls offer_cdr() on the raw message: the double
read from the CDR bytes (no message object), a check against the physical limits
(valve_sim.core.limits), a counter and, for a good value, a few assignments; not
even the clock is read (the next tick stamps the arrival). The tick uses the last
good value; a flood of messages costs the tick nothing but these callbacks, and
nothing is logged per message: report() gives the rejections since the last
report, for one rate-limited warning.
"""

import struct

from valve_sim.core.limits import inlet_flow_problem


FLOAT64_CDR = struct.Struct('<d')  # std_msgs/Float64 data after the 4-byte CDR header
CDR_HEADER = 4


class InletFlowInput:
    """
    The inlet flow [m^3/s]: the last good value and counts of what was received.

    flow: the flow held until a good message comes; max_inlet_flow [m^3/s]: the limit.
    accepted and rejected count every message offered; changed is set by a good value
    that differs from the one held (cleared by the node when it used it).
    """

    def __init__(self, flow, max_inlet_flow):
        self.flow = flow
        self.max_inlet_flow = max_inlet_flow
        self.accepted = 0
        self.rejected = 0
        self.changed = False
        self.received = False  # a good message came since the last stamp()
        self.received_ns = None  # clock time [ns] of the tick after the last good message
        self.last_rejection = ''
        self._reported_rejected = 0

    def offer(self, flow):
        """Take a received value: keep it if it is a valid inlet flow, count it either way."""
        problem = inlet_flow_problem(flow, self.max_inlet_flow)
        if problem is None:
            self.accepted += 1
            self.changed = self.changed or flow != self.flow
            self.flow = flow
            self.received = True
            return True
        self.rejected += 1
        self.last_rejection = problem
        return False

    def offer_cdr(self, data):
        """Take a serialized std_msgs/Float64 (little-endian CDR, as ROS 2 sends it)."""
        if len(data) < CDR_HEADER + FLOAT64_CDR.size or data[1] != 1:
            self.rejected += 1
            self.last_rejection = f'not a little-endian std_msgs/Float64 ({len(data)} bytes)'
            return False
        return self.offer(FLOAT64_CDR.unpack_from(data, CDR_HEADER)[0])

    def stamp(self, now_ns):
        """At a tick: a good message received since the last tick arrived by now_ns [ns]."""
        if self.received:
            self.received = False
            self.received_ns = now_ns

    def report(self):
        """Return (rejections since the last report, the last reason) and start a new count."""
        new = self.rejected - self._reported_rejected
        self._reported_rejected = self.rejected
        return new, self.last_rejection
