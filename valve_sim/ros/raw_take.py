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
Taking serialized messages from a raw subscription no executor runs, counting the lost ones.

Both nodes take some messages themselves instead of letting the executor call back
for each one: valve_node its inputs at the start of a tick (valve_inputs), analyser_node
every recorded topic in its drain. take() locks the subscription's handle once and
takes messages until the queue is empty, a limit or a deadline; each message goes to
the taker's receive(data, info) as CDR bytes and rmw's message info. What the
middleware dropped before it was taken shows, for a topic with a single publisher,
as gaps in that publisher's publication sequence numbers: counted in lost (the owner
says whether the topic has a single publisher). A publisher that starts again counts
from 1: a sequence number that goes back is no loss.
"""

import time


class RawTaker:
    """
    One raw subscription's taking: messages handed to receive(data, info), gaps counted.

    receive: a callable (CDR bytes, message info dict), or None for a subclass that
    defines receive(). lost: the messages a single publisher sent that never came;
    single_publisher: set by the owner from the graph (with several publishers their
    sequence numbers interleave and say nothing).
    """

    def __init__(self, receive=None):
        if receive is not None:
            self.receive = receive
        self.single_publisher = False
        self.lost = 0
        self.last_sequence = None

    def receive(self, data, info):
        """Take one message: its CDR bytes and rmw's message info."""
        raise NotImplementedError

    def take(self, subscription, limit=None, deadline_ns=None):
        """
        Take queued messages of subscription: all, or up to limit, none after deadline_ns.

        subscription: an rclpy raw subscription (raw=True) that no executor runs;
        deadline_ns [ns] on time.perf_counter_ns(). Returns how many were taken.
        """
        handle, message_type, receive = subscription.handle, subscription.msg_type, self.receive
        taken = 0
        with handle:
            while (limit is None or taken < limit) and (
                deadline_ns is None or time.perf_counter_ns() < deadline_ns
            ):
                message = handle.take_message(message_type, True)
                if message is None:
                    break
                data, info = message
                self._count_gap(info['publication_sequence_number'])
                receive(data, info)
                taken += 1
        return taken

    def _count_gap(self, sequence):
        """Count the messages missing before this one, if they all came from one publisher."""
        last = self.last_sequence
        if self.single_publisher and last is not None and sequence is not None:
            self.lost += max(sequence - last - 1, 0)
        self.last_sequence = sequence
