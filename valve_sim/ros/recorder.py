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
analyser_node's recorder: each wanted topic subscribed as rosbag2 does, taken raw, written.

Recorder subscribes a node to each wanted topic once it has a publisher, with the QoS
rosbag2 would choose (subscription_qos), of whatever type the graph reports for it,
and adds it to the bag with its publishers' offers. drain() takes every queued
message of every topic (valve_sim.ros.raw_take, the taker valve_node's inputs use),
writes it to the bag, counts it and the messages a single publisher lost, and hands
the analysed topics' messages to the measures publisher (measures_publisher.StepMeasures),
which also says which type of a topic it reads and how (type_to_record, extractor).
status() is the recording status analyser_node publishes on /diagnostics. The node's
docstring (valve_sim.ros.analyser_node) says what is recorded and how nothing is lost.

Log and publish times: the receive and send times, on the system clock; on /clock
(use_sim_time, as in lockstep) the model's time instead, as rosbag2 records with
use_sim_time: a message with a header its stamp (the model time it is of, exact
whatever the drain's lag, so two runs of a scenario give the same times), another
the node's clock at the drain.
"""

import functools
import struct
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from valve_sim.recording.cdr import STAMP, STAMP_OFFSET
from valve_sim.recording.valve_topics import message_class, PARAMETER_EVENTS_TOPIC
from valve_sim.ros.raw_take import RawTaker
from valve_sim.ros.start_parameters import StartParameters, STATUS_KEY


READABLE_TYPE_GRACE = 5.0  # [s] an analysed topic's wait for a publisher of a type it reads


class RecordedTopic(RawTaker):
    """
    A subscribed topic: its raw subscription, type, bag channel, extractor, counters.

    Taken by the drain (RawTaker.take), each message handed to receive(data, info);
    lost counts the gaps of a single publisher's sequence numbers.
    """

    def __init__(self, subscription, type_name, receive, extractor=None, channel=None, qos=''):
        super().__init__(receive)
        self.subscription, self.type_name = subscription, type_name
        self.extractor, self.channel = extractor, channel
        self.count = 0
        self.qos = qos  # reliability and durability of the subscription
        fields = list(subscription.msg_type.get_fields_and_field_types().items())
        self.stamped = bool(fields) and fields[0] == ('header', 'std_msgs/Header')


def model_time(recorded, data, clock_ns):
    """Return a message's model time [ns]: its header stamp if it has one, else clock_ns."""
    if recorded.stamped:
        try:
            sec, nanosec = STAMP.unpack_from(data, STAMP_OFFSET)
        except struct.error:
            return clock_ns
        if sec >= 0:
            return sec * 1_000_000_000 + nanosec
    return clock_ns


def subscription_qos(offers, depth):
    """
    Return the QoSProfile to record a topic with, as rosbag2 chooses it.

    offers: the QoSProfiles of its publishers. Reliable only if every publisher is
    (a reliable subscription never hears a best-effort publisher), else best effort;
    transient local only if every publisher is (so their stored samples come too),
    else volatile. Keep last depth messages.
    """
    def every(policy_of, value):
        return all(policy_of(offer) == value for offer in offers)

    return QoSProfile(
        depth=depth,
        reliability=(
            ReliabilityPolicy.RELIABLE
            if every(lambda offer: offer.reliability, ReliabilityPolicy.RELIABLE)
            else ReliabilityPolicy.BEST_EFFORT
        ),
        durability=(
            DurabilityPolicy.TRANSIENT_LOCAL
            if every(lambda offer: offer.durability, DurabilityPolicy.TRANSIENT_LOCAL)
            else DurabilityPolicy.VOLATILE
        ),
    )


def qos_name(qos):
    """Return 'reliable/volatile' style name of a QoSProfile's reliability and durability."""
    return f'{qos.reliability.name.lower()}/{qos.durability.name.lower()}'


def qos_offer(qos):
    """
    Convert an rclpy QoSProfile to an offer dict.

    The dict is one offer as valve_sim.recording.bag.qos_profiles_yaml() takes them.
    """
    return {
        'history': qos.history.name.lower(),
        'depth': qos.depth,
        'reliability': qos.reliability.name.lower(),
        'durability': qos.durability.name.lower(),
        'deadline_ns': qos.deadline.nanoseconds,
        'lifespan_ns': qos.lifespan.nanoseconds,
        'liveliness': qos.liveliness.name.lower(),
        'liveliness_lease_duration_ns': qos.liveliness_lease_duration.nanoseconds,
        'avoid_ros_namespace_conventions': qos.avoid_ros_namespace_conventions,
    }


class Recorder:
    """
    Records a node's wanted topics to a BagWriter; hands the analysed ones to the measures.

    node: the rclpy Node that subscribes (and logs); bag: the BagWriter; wanted: the
    topics to record (full names, in order); optional: those of them a status does not
    wait for until they have a publisher; queue_depth: each subscription's queue;
    flush_interval [s]: the longest time written data waits for its chunk to be
    flushed; measures: the measures publisher (type_to_record, extractor, add); kept:
    the last recording's handed_over() subscriptions, after a restart; parameter_clients:
    the node's clients of valve_node's parameter services (StartParameters).
    """

    def __init__(self, node, bag, wanted, optional, queue_depth, flush_interval, measures,
                 kept=None, parameter_clients=None):
        self.node, self.bag, self.measures = node, bag, measures
        # {topic: RecordedTopic} of the recording before a restart: its subscription is
        # used again if it fits (no new match, no message missed meanwhile), else dropped
        self.kept = dict(kept or {})
        self.wanted, self.optional = wanted, optional
        self.queue_depth, self.flush_interval = queue_depth, flush_interval
        self.last_flush = self.last_loss_warning = time.monotonic()
        self.recorded = {}
        self.unrecordable = {}  # topic -> why it cannot be recorded
        self.other_types = {}  # recorded topic -> types of other publishers, not recorded
        self.unreadable_since = {}  # topic -> when only unreadable types were first seen
        self.clock_ns = None  # the node's /clock time at this drain, None off /clock
        # valve_node's values at the start, written on /parameter_events (start_parameters)
        self.start_parameters = StartParameters(
            node, measures.signal_map.topics['supply_pressure'], self._write_start_parameters,
            {} if parameter_clients is None else parameter_clients)

    @property
    def subscriptions(self):
        """Return the recorded (and kept) topics' subscriptions: the drain takes them."""
        return {recorded.subscription
                for recorded in (*self.recorded.values(), *self.kept.values())}

    def handed_over(self):
        """
        Return {topic: RecordedTopic} whose subscriptions a restart's recording may keep.

        A transient-local topic's subscription is dropped here instead: a new one gets
        its publishers' history again, as a new node's would.
        """
        kept = {}
        for topic, recorded in self.recorded.items():
            if recorded.qos.endswith('transient_local'):
                self.node.destroy_subscription(recorded.subscription)
            else:
                kept[topic] = recorded
        self.recorded = {}
        self.start_parameters.close()
        return kept

    def discover(self):
        """
        Subscribe to each wanted topic once it has a publisher, with a QoS its publishers match.

        Also note who publishes what.
        """
        types = dict(self.node.get_topic_names_and_types())
        for topic in [t for t in self.wanted if t not in self.recorded and t in types]:
            offers = [info.qos_profile for info in self.node.get_publishers_info_by_topic(topic)]
            if not offers:
                continue  # only subscribers so far: the publishers' QoS decides ours
            type_name, readable = self.measures.type_to_record(topic, types[topic])
            if not readable and self._still_waiting_for_a_readable_type(topic):
                continue
            try:
                message_type = message_class(type_name)
            except (ImportError, AttributeError, ValueError) as error:
                self.unrecordable[topic] = f'no message type {type_name} here'
                self.node.get_logger().error(
                    f'cannot record {topic}: no message type {type_name} ({error})'
                )
                self.wanted.pop(topic)
                continue
            qos = subscription_qos(offers, self.queue_depth)
            # In the bag from now on, with its publishers' offers, as rosbag2 creates a topic
            # when it subscribes (listed with its count even if no message ever comes).
            channel = self.bag.add_topic(topic, type_name, [qos_offer(o) for o in offers])
            self.recorded[topic] = recorded = RecordedTopic(
                self._subscription(topic, message_type, type_name, qos),
                type_name,
                None,
                self.measures.extractor(topic, type_name),
                channel=channel,
                qos=qos_name(qos),
            )
            recorded.receive = functools.partial(self._record, recorded)
            self.node.get_logger().info(
                f'recording {topic} ({type_name}) with QoS {qos_name(qos)}, depth '
                f'{qos.depth}, for {len(offers)} publisher(s) offering '
                f'{", ".join(sorted({qos_name(offer) for offer in offers}))}'
            )
        for topic, recorded in self.recorded.items():
            recorded.single_publisher = self.node.count_publishers(topic) == 1
            others = sorted(set(types.get(topic, ())) - {recorded.type_name})
            if others and others != self.other_types.get(topic):
                self.node.get_logger().warn(
                    f'{topic} also has publishers of {", ".join(others)}: recording '
                    f'{recorded.type_name} only (rosbag2 would record neither: it records a '
                    'topic of one type only)'
                )
            self.other_types[topic] = others
        for kept in self.kept.values():  # no longer wanted, or no publisher now
            self.node.destroy_subscription(kept.subscription)
        self.kept = {}
        if PARAMETER_EVENTS_TOPIC in self.recorded:
            self.start_parameters.poll()

    def _subscription(self, topic, message_type, type_name, qos):
        """Return the subscription of a topic to record: the one kept if it fits, else new."""
        kept = self.kept.pop(topic, None)
        if kept is not None and (kept.type_name, kept.qos, kept.subscription.qos_profile.depth) \
                == (type_name, qos_name(qos), qos.depth):
            return kept.subscription
        if kept is not None:
            self.node.destroy_subscription(kept.subscription)
        return self.node.create_subscription(message_type, topic, lambda _: None, qos, raw=True)

    def _still_waiting_for_a_readable_type(self, topic):
        """
        Whether to wait before recording an analysed topic of no type the analysis reads.

        Discovery reports publishers in any order: a rogue publisher found first would
        otherwise fix the recorded type before valve_node's is seen (only the rogue's
        messages go unrecorded meanwhile). After READABLE_TYPE_GRACE s without a readable
        publisher the other type is recorded, as rosbag2 would.
        """
        first_seen = self.unreadable_since.setdefault(topic, time.monotonic())
        return time.monotonic() - first_seen < READABLE_TYPE_GRACE

    def drain(self):
        """Take every queued message of every topic: write it, and analyse those of the signals."""
        clock = self.node.get_clock()
        self.clock_ns = clock.now().nanoseconds if clock.ros_time_is_active else None
        for topic, recorded in self.recorded.items():
            lost = recorded.lost
            recorded.take(recorded.subscription)
            if recorded.lost > lost:
                self._warn_lost(topic, recorded.lost)
        if self.start_parameters.pending:  # an answer acted on at once, not at discovery
            self.start_parameters.advance()
        if time.monotonic() - self.last_flush >= self.flush_interval:
            self.bag.flush()
            self.last_flush = time.monotonic()

    def _record(self, recorded, data, info):
        """Write one message taken from a recorded topic; analyse it if it carries a signal."""
        received = info['received_timestamp']
        if self.clock_ns is None:
            self.bag.write(recorded.channel, data, received, info['source_timestamp'])
        else:  # on /clock: the model's time, for both
            model_ns = model_time(recorded, data, self.clock_ns)
            self.bag.write(recorded.channel, data, model_ns, model_ns)
        recorded.count += 1
        if recorded.extractor:
            self.measures.add(recorded, data, received)

    def _write_start_parameters(self, data, received_ns):
        """Write the start snapshot (a ParameterEvent) after what /parameter_events has queued."""
        self.drain()
        self._record(self.recorded[PARAMETER_EVENTS_TOPIC], data,
                     {'received_timestamp': received_ns, 'source_timestamp': received_ns})

    def _warn_lost(self, topic, lost):
        """
        Log lost messages at most once a second.

        rclpy's own throttling inspects the stack: too slow here.
        """
        if time.monotonic() - self.last_loss_warning >= 1.0:
            self.last_loss_warning = time.monotonic()
            self.node.get_logger().warn(
                f'{topic}: {lost} message(s) lost so far before reaching the analyser '
                '(gaps in the publication sequence numbers)'
            )

    def status(self, steps_measured, refused_clock):
        """
        Return the recording status: (level, message, {key: value}).

        ERROR once a topic cannot be recorded; else WARN while a topic has no
        message or when some were lost; else OK. An optional topic
        counts once it has a publisher; /parameter_events is never waited for (it
        carries a message only when a parameter changes).
        """
        counts = {
            topic: (self.recorded[topic].count if topic in self.recorded else 0)
            for topic in self.wanted
            if topic in self.recorded or topic not in self.optional
        }
        lost = {topic: recorded.lost for topic, recorded in self.recorded.items() if recorded.lost}
        waiting = [topic for topic, count in counts.items()
                   if count == 0 and topic != PARAMETER_EVENTS_TOPIC]
        values = {
            'file': str(self.bag.path),
            'messages': str(self.bag.message_count),
            'steps measured': str(steps_measured),
            **{f'messages {topic}': str(count) for topic, count in counts.items()},
            **{f'qos {topic}': recorded.qos for topic, recorded in self.recorded.items()},
            **{f'lost {topic}': str(count) for topic, count in lost.items()},
        }
        values.update({f'cannot record {t}': why for t, why in self.unrecordable.items()})
        mixed = {topic: others for topic, others in self.other_types.items() if others}
        values.update(
            {f'other types on {topic}': ', '.join(others) for topic, others in mixed.items()}
        )
        values['refused /clock messages'] = str(refused_clock)
        if self.start_parameters.read:
            values[STATUS_KEY] = self.start_parameters.status()
        message = (
            f'cannot record {", ".join(self.unrecordable)}'
            if self.unrecordable
            else f'no messages yet on {", ".join(waiting)}'
            if waiting
            else 'publishers of other types on '
            + ', '.join(f'{t} ({", ".join(o)}: not recorded)' for t, o in mixed.items())
            if mixed
            else f'{sum(lost.values())} message(s) lost before reaching the analyser'
            if lost
            else f'recording to {self.bag.path.name}'
        )
        level = (
            DiagnosticStatus.ERROR
            if self.unrecordable
            else DiagnosticStatus.WARN
            if waiting or lost or mixed or refused_clock
            else DiagnosticStatus.OK
        )
        return level, message, values
