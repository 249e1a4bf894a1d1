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

"""Taking serialized messages from a raw subscription (RawTaker): no node, no middleware."""

import time

import pytest
from valve_sim.ros.raw_take import RawTaker


class Queue:
    """A raw subscription's handle: (bytes, message info) queued, locks counted."""

    msg_type = object()

    def __init__(self, sequences):
        self.queue = [
            (bytes([(n or 0) % 256]), {'publication_sequence_number': n}) for n in sequences
        ]
        self.handle = self
        self.locks = 0

    def __enter__(self):
        self.locks += 1

    def __exit__(self, *_):
        return False

    def take_message(self, message_type, raw):
        assert message_type is self.msg_type and raw
        return self.queue.pop(0) if self.queue else None


@pytest.fixture
def received():
    return []


@pytest.fixture
def taker(received):
    return RawTaker(lambda data, info: received.append((data, info)))


def test_a_take_hands_every_queued_message_over_in_order_under_one_lock(taker, received):
    queue = Queue([1, 2, 3])
    assert taker.take(queue) == 3
    assert [data for data, _ in received] == [b'\x01', b'\x02', b'\x03']
    assert received[0][1] == {'publication_sequence_number': 1}
    assert queue.locks == 1 and taker.take(queue) == 0


def test_a_take_stops_at_its_limit_and_takes_none_after_its_deadline(taker, received):
    queue = Queue([1, 2, 3])
    assert taker.take(queue, limit=2) == 2
    assert taker.take(queue, deadline_ns=time.perf_counter_ns() - 1) == 0
    assert taker.take(queue, 5, time.perf_counter_ns() + 10**9) == 1
    assert len(received) == 3


def test_gaps_count_as_lost_only_from_a_single_publisher(taker):
    taker.take(Queue([1, 4]))  # publishers unknown yet: a gap says nothing
    assert taker.lost == 0
    taker.single_publisher = True
    taker.take(Queue([5, 6, 10]))
    assert taker.lost == 3  # 7, 8, 9
    taker.take(Queue([1, 3]))  # the publisher started again: counts from 1, lost 2
    assert taker.lost == 4
    taker.take(Queue([None, 9]))  # no sequence number (rmw without them): no count
    assert taker.lost == 4


def test_a_subclass_defines_receive():
    class Counting(RawTaker):
        count = 0

        def receive(self, data, info):
            self.count += 1

    counting = Counting()
    counting.take(Queue([1, 2]))
    assert counting.count == 2
    with pytest.raises(NotImplementedError):
        RawTaker().take(Queue([1]))
