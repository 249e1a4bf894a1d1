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
analyser_node over real DDS.

A simulated step published at 1 kHz, recorded, measured live and offline.
"""

from contextlib import contextmanager
import json
import re
import signal
import subprocess
import sys
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from mcap.reader import make_reader
from mcap.records import Message
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
import pytest
import rclpy
from rclpy.parameter import Parameter
from valve_harness import flushed
from valve_sim.analysis.recorded_steps import analyse
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import relief_flows
from valve_sim.recording.bag import BagReader, message_definition
from valve_sim.recording.signal_reader import read_recording
from valve_sim.ros.analyser_node import parameter_names, ValveAnalyser
from valve_sim.ros.measures_publisher import measures_from_message, MEASURES_QOS
from valve_sim.ros.replay import Replay
import yaml


TIMEOUT = 60.0  # [s] for anything that waits on another process
# A publisher of diagnostic_msgs/KeyValue on supply_pressure, until killed.
ROGUE_PUBLISHER = """
import rclpy, time
from diagnostic_msgs.msg import KeyValue
rclpy.init()
node = rclpy.create_node('rogue')
publisher = node.create_publisher(KeyValue, 'supply_pressure', 10)
while True:
    publisher.publish(KeyValue(key='rogue', value='x'))
    time.sleep(0.01)
"""


def tick_relief(waveforms):
    """Return the relief flow and its parts at each sample of the reference valve's run."""
    return relief_flows(load_parameters().params, waveforms)


@contextmanager
def running_analyser(folder, *parameters):
    """
    Run an analyser_node process recording into folder.

    The process is killed on the way out if a test left it running.
    """
    arguments = [
        argument
        for parameter in (f'output_dir:={folder}', *parameters)
        for argument in ('-p', parameter)
    ]
    process = subprocess.Popen(
        [sys.executable, '-m', 'valve_sim.ros.analyser_node', '--ros-args', *arguments],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        yield process
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()


@pytest.fixture(scope='module')
def recording(node, tick_waveforms, tmp_path_factory):
    """
    Run the analyser once.

    The step replayed, its measures received, every message delivered to the analyser
    (the measures come 50 ms of messages before the end), then SIGTERM.
    """
    folder = tmp_path_factory.mktemp('recording')
    messages = []
    node.create_subscription(DiagnosticArray, 'step_measures', messages.append, MEASURES_QOS)
    executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    with running_analyser(folder) as analyser:
        replay = Replay(node)
        replay.wait_for_subscribers(timeout=TIMEOUT)
        replay.publish(tick_waveforms, time.time_ns(), every=1, relief=tick_relief(tick_waveforms))
        deadline = time.monotonic() + TIMEOUT
        while not messages:
            executor.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, 'no step_measures message'
        executor.remove_node(node)
        replay.wait_until_delivered(timeout=TIMEOUT)  # published is not yet received
        analyser.send_signal(signal.SIGTERM)
        log = analyser.communicate(timeout=TIMEOUT)[0]
    bag = next(folder.glob('*.mcap'))
    return {
        'code': analyser.returncode,
        'log': log,
        'bag': bag,
        'published': replay.published,
        'messages': messages,
        'records': json.loads(bag.with_suffix('.measures.json').read_text())['steps'],
    }


def test_sigterm_closes_the_file(recording):
    assert recording['code'] == 0, recording['log']
    assert 'closed' in recording['log'] and 'Traceback' not in recording['log']
    with open(recording['bag'], 'rb') as stream:
        assert make_reader(stream).get_summary() is not None  # summary and footer written


def test_every_published_message_is_recorded(recording):
    with open(recording['bag'], 'rb') as stream:
        summary = make_reader(stream).get_summary()
    counts = {
        summary.channels[i].topic: n for i, n in summary.statistics.channel_message_counts.items()
    }
    assert {topic: counts.get('/' + topic) for topic in recording['published']} == recording[
        'published'
    ]


def test_live_measures_equal_offline_analysis(recording):
    records = recording['records']
    assert len(records) == 1 and records[0]['direction'] == 1
    assert all(records[0][name] is not None for name in MEASURE_NAMES), records[0]['reasons']
    assert records == analyse(read_recording(recording['bag']))
    published = measures_from_message(recording['messages'][0])
    assert published == {name: records[0][name] for name in MEASURE_NAMES}
    # the step's time on the bag's axis (the epoch) and from the recording's first sample
    message = recording['messages'][0].status[0].message
    assert re.match(r'step up at t = \d+\.\d{6} s \(\d\.\d{4} s after the first sample\): ',
                    message), message


def test_recording_decodes_with_mcap_ros2_and_rosbags(recording):
    from rosbags.highlevel import AnyReader

    with open(recording['bag'], 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            assert (channel.message_encoding, schema.encoding) == ('cdr', 'ros2msg')
            assert schema.data.decode() == message_definition(schema.name)
            offers = yaml.safe_load(channel.metadata['offered_qos_profiles'])
            assert offers and offers[0]['reliability'] == 'reliable'
        decoded = sum(1 for _ in reader.iter_decoded_messages())
    assert decoded == summary.statistics.message_count
    with AnyReader([recording['bag']]) as bag:
        connections = [c for c in bag.connections if c.topic == '/joint_states']
        positions = [
            bag.deserialize(raw, c.msgtype).position for c, _, raw in bag.messages(connections)
        ]
    assert len(positions) == recording['published']['joint_states']


def test_hard_kill_leaves_every_flushed_chunk_readable(node, tick_waveforms, tmp_path):
    with running_analyser(tmp_path, 'flush_interval:=0.2') as analyser:
        replay = Replay(node)
        replay.wait_for_subscribers(timeout=TIMEOUT)
        replay.publish(tick_waveforms, time.time_ns(), every=2, relief=tick_relief(tick_waveforms))
        published, topics = (
            sum(replay.published.values()),
            {'/' + topic for topic in replay.published},
        )
        bag = next(tmp_path.glob('*.mcap'))
        deadline = time.monotonic() + TIMEOUT
        while flushed(bag, topics) < published:
            assert time.monotonic() < deadline, 'the analyser did not flush what it received'
            time.sleep(0.2)
        analyser.kill()
        analyser.wait(timeout=TIMEOUT)
        assert analyser.returncode == -signal.SIGKILL
    reader = BagReader(bag)
    assert sum(1 for _ in reader.messages(topics)) == published
    assert 'ends before its footer' in reader.problem
    records = []
    with (
        open(bag, 'rb') as stream,
        pytest.raises(Exception),
    ):  # the mcap library reads it as far as it goes
        for record in StreamReader(stream).records:
            records.append(record)
    assert sum(isinstance(record, Message) for record in records) >= published
    assert read_recording(bag).problem


def test_unwritable_output_dir_is_an_error_at_start(tmp_path):
    blocker = tmp_path / 'file'
    blocker.write_text('')
    with running_analyser(blocker / 'recordings') as analyser:
        log = analyser.communicate(timeout=TIMEOUT)[0]
    assert analyser.returncode == 1
    assert (
        f"parameter 'output_dir': output folder {blocker / 'recordings'} cannot be created: "
        'Not a directory'
    ) in log
    assert 'Traceback' not in log


def test_a_best_effort_publisher_is_recorded_and_its_qos_reported(node, tmp_path):
    """As rosbag2 does: a SensorDataQoS (best-effort) topic is subscribed best effort."""
    from rclpy.qos import qos_profile_sensor_data
    from std_msgs.msg import Float64

    code, log, _ = record_while(
        node,
        tmp_path,
        node.create_publisher(Float64, 'inlet_flow', qos_profile_sensor_data),
        Float64(data=1e-4),
        lambda values: values.get('qos /inlet_flow') == 'best_effort/volatile'
        and int(values.get('messages /inlet_flow', 0)) > 0,
    )
    assert code == 0, log
    assert 'recording /inlet_flow (std_msgs/msg/Float64) with QoS best_effort/volatile' in log
    bag = next(tmp_path.glob('*.mcap'))
    assert sum(1 for _ in BagReader(bag).messages({'/inlet_flow'})) > 0


def record_while(node, folder, publisher, message, done, *parameters):
    """
    Run an analyser into folder, publishing message on publisher until done(last status).

    done gets the latest recording status's values ({} before one came). Returns
    (exit code after SIGINT, its log, that status).
    """
    from valve_sim.ros.analyser_node import NODE_NAME, RECORDING_TASK

    statuses = []
    subscription = node.create_subscription(
        DiagnosticArray,
        '/diagnostics',
        lambda array: statuses.extend(
            s for s in array.status if s.name == f'{NODE_NAME}: {RECORDING_TASK}'
        ),
        10,
    )
    executor = rclpy.executors.SingleThreadedExecutor(context=node.context)
    executor.add_node(node)

    def latest():
        return {kv.key: kv.value for status in statuses[-1:] for kv in status.values}

    try:
        with running_analyser(folder, *parameters) as analyser:
            deadline = time.monotonic() + TIMEOUT
            while not done(latest()):
                assert analyser.poll() is None, analyser.communicate()[0]
                assert time.monotonic() < deadline, f'timed out, last status: {statuses[-1:]}'
                publisher.publish(message)
                executor.spin_once(timeout_sec=0.01)
            status = statuses[-1]
            analyser.send_signal(signal.SIGINT)
            log = analyser.communicate(timeout=TIMEOUT)[0]
    finally:
        executor.remove_node(node)
        node.destroy_publisher(publisher)
        node.destroy_subscription(subscription)
    return analyser.returncode, log, status


def test_a_rogue_type_on_an_analysed_topic_does_not_stop_its_recording(node, tmp_path):
    """
    A publisher of another type on supply_pressure, whose type name sorts first.

    The analyser records the FluidPressure the analysis reads (rosbag2 would record
    neither), raises WARN naming the other type, and the bag holds the pressure.
    """
    from sensor_msgs.msg import FluidPressure

    # Another process: one participant cannot hold two types on a topic.
    rogue = subprocess.Popen([sys.executable, '-c', ROGUE_PUBLISHER])
    try:
        code, log, status = record_while(
            node,
            tmp_path,
            node.create_publisher(FluidPressure, 'supply_pressure', 10),
            FluidPressure(fluid_pressure=7.1e6),
            lambda values: 'diagnostic_msgs/msg/KeyValue'
            in values.get('other types on /supply_pressure', '')
            and int(values.get('messages /supply_pressure', 0)) > 100,
        )
    finally:
        rogue.kill()
        rogue.wait()
    assert code == 0 and status.level == DiagnosticStatus.WARN, log
    bag = next(tmp_path.glob('*.mcap'))
    recorded = [s.name for _, s, _ in BagReader(bag).messages({'/supply_pressure'})]
    assert len(recorded) > 100 and set(recorded) == {'sensor_msgs/msg/FluidPressure'}


@pytest.mark.parametrize('sec, nanosec', [(-3, 0), (2**31 - 1, 4_000_000_000)])
def test_a_clock_the_analyser_cannot_represent_is_ignored_and_the_bag_closed(
    node, tmp_path, sec, nanosec
):
    """A /clock of negative seconds or past 2^31 s: ignored, counted, the bag closed on SIGINT."""
    from builtin_interfaces.msg import Time
    from rosgraph_msgs.msg import Clock
    from valve_sim.recording.mcap_scan import diagnose

    code, log, _ = record_while(
        node,
        tmp_path,
        node.create_publisher(Clock, '/clock', 10),
        Clock(clock=Time(sec=sec, nanosec=nanosec)),
        lambda values: int(values.get('refused /clock messages', 0)) > 0,
        'use_sim_time:=true',
    )
    assert code == 0 and 'Traceback' not in log, log
    assert diagnose(next(tmp_path.glob('*.mcap'))).damage is None, 'closed, with its footer'


def test_help_lists_every_parameter_the_node_declares(context, tmp_path):
    """Derived from the tables the node declares: --help and the launch file's check agree."""
    node = ValveAnalyser(
        context=context, parameter_overrides=[Parameter('output_dir', value=str(tmp_path))]
    )
    try:
        declared = set(node._parameters) - {'use_sim_time', 'start_type_description_service'}
    finally:
        node.close()
        node.destroy_node()
    assert declared == set(parameter_names())
    shown = subprocess.run([sys.executable, '-m', 'valve_sim.ros.analyser_node', '--help'],
                           capture_output=True, text=True, timeout=TIMEOUT).stdout
    listed = ' '.join(shown.split('ROS parameters', 1)[1].split())
    for name in declared:
        assert re.search(rf'\b{name}\b', listed), name
