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
Publish a simulated run as valve_node would, tick by tick.

It is a known load for the analyser's tests and bench.
Every tick publishes valve_topics.TickMessages filled with one waveform sample, paced at
the tick period on the monotonic clock (a late tick is published at once, so the
count is exact and the mean rate holds). Publishers are reliable, KEEP_LAST
with QUEUE_DEPTH: a reliable writer drops its oldest unacknowledged sample when
its queue is full, so the depth must cover the longest stall of the machine (a
loaded 2-core machine stalls for a few hundred ms at times). wait_for_subscribers()
before publish() makes sure that nothing published is lost to discovery;
wait_until_delivered() after it, that every message has reached every subscriber
(publish() only queues them), before the subscriber is stopped.
"""

import time

from valve_sim.core.errors import WaitTimeoutError
from valve_sim.core.parameters import STANDARD_ATMOSPHERE
from valve_sim.recording.valve_topics import (
    message_class,
    NS_PER_S,
    TICK_TOPICS,
    TickMessages,
    TOPIC_TYPES,
)


QUEUE_DEPTH = 1000  # [messages] 1 s at 1 kHz


class Replay:
    """valve_node's tick publishers on a given rclpy node."""

    def __init__(self, node, ambient_pressure=STANDARD_ATMOSPHERE):
        self.node, self.ambient_pressure = node, ambient_pressure
        self.publishers = {
            topic: node.create_publisher(message_class(TOPIC_TYPES[topic]), topic, QUEUE_DEPTH)
            for topic in TICK_TOPICS
        }
        self.published = dict.fromkeys(TICK_TOPICS, 0)

    def wait_for_subscribers(self, count=1, timeout=60.0):
        """Wait until every publisher is matched with count subscribers; raises TimeoutError."""
        deadline = time.monotonic() + timeout
        while any(p.get_subscription_count() < count for p in self.publishers.values()):
            if time.monotonic() > deadline:
                raise WaitTimeoutError(
                    f'not {count} subscriber(s) for every valve topic within {timeout:g} s'
                )
            time.sleep(0.01)

    def wait_until_delivered(self, timeout=60.0):
        """Wait until every subscriber acknowledged every message; raises TimeoutError."""
        from rclpy.duration import Duration

        deadline = time.monotonic() + timeout
        for topic, publisher in self.publishers.items():
            left = max(deadline - time.monotonic(), 0.0)
            if not publisher.wait_for_all_acked(Duration(nanoseconds=round(left * 1e9))):
                raise WaitTimeoutError(
                    f'{topic}: not every message acknowledged within {timeout:g} s'
                )

    def publish(self, waveforms, start_time_ns, period=1e-3, every=10, relief=None):
        """
        Publish every every-th sample of waveforms, one tick each period [s].

        Each tick is stamped start_time_ns + its model time. relief: the relief flow and
        its parts per sample (simulation.relief_flows); None: relief_flow publishes nothing.
        """
        started = time.monotonic()
        messages = TickMessages()
        for tick, index in enumerate(range(0, len(waveforms.time), every)):
            delay = started + tick * period - time.monotonic()
            if delay > 0.0:
                time.sleep(delay)
            time_ns = start_time_ns + round(waveforms.time[index] * NS_PER_S)
            for topic, data in messages.fill(
                time_ns,
                waveforms.states[index],
                waveforms.inlet_flow[index],
                self.ambient_pressure,
                tank_pressure=0.0 if waveforms.tank_pressure is None
                else waveforms.tank_pressure[index],
                relief=None if relief is None else relief[index].tolist(),
            ):
                self.publishers[topic].publish(data)
                self.published[topic] += 1
