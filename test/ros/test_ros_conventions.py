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
ROS conventions: /diagnostics as diagnostic_updater names it, frames, the Foxglove live view.

One valve_node runs renamed (--ros-args -r __node:=renamed_valve) with its Foxglove
server on a free port; the analyser runs in this process, renamed too, recording a
replayed run into a bag folder.
"""

import asyncio
import json
from pathlib import Path
import re
import struct
import subprocess
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from mcap.records import Schema
from mcap_ros2.decoder import DecoderFactory
import pytest
import rclpy
from rclpy.parameter import Parameter
from valve_harness import running_valve, TIMEOUT
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, relief_flows, simulate
from valve_sim.recording.valve_topics import message_class, TICK_TOPICS, TOPIC_TYPES
from valve_sim.ros import analyser_node, recorder
from valve_sim.ros.live_view import layout_path
from valve_sim.ros.replay import Replay


pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures('valve_node_kernels')]

RENAMED = 'renamed_valve'
INITIAL_FLOW = 5.0 * LITRE_PER_MINUTE
PUBLISHED = {'/' + topic: TOPIC_TYPES[topic] for topic in TICK_TOPICS} | {
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'
}  # what valve_node publishes (in the root namespace)


@pytest.fixture(scope='module')
def renamed_valve(context, tmp_path_factory):
    """Yield (probe, Foxglove port) of a valve_node renamed at start, input timeout 0.5 s."""
    log = tmp_path_factory.mktemp('renamed_valve') / 'valve_node.log'
    with running_valve(
        context,
        log,
        '-r',
        f'__node:={RENAMED}',
        '-p',
        'input_timeout:=0.5',
        node_name=RENAMED,
        options=('--foxglove', '0'),
    ) as (_, probe):
        found = re.search(r'Foxglove live view on ws://127\.0\.0\.1:(\d+)', log.read_text())
        assert found, log.read_text()
        yield probe, int(found[1])


async def foxglove_samples(port, topic, count):
    """
    Subscribe to topic on the Foxglove server as the app does.

    Returns (advertised channels by topic, [(log_time, payload)] of count messages).
    """
    import websockets

    async with websockets.connect(
        f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1', 'foxglove.websocket.v1']
    ) as socket:
        channels = {}
        while topic not in channels:
            frame = await asyncio.wait_for(socket.recv(), TIMEOUT)
            if isinstance(frame, str) and json.loads(frame)['op'] == 'advertise':
                channels.update({c['topic']: c for c in json.loads(frame)['channels']})
        subscription = {'id': 7, 'channelId': channels[topic]['id']}
        await socket.send(json.dumps({'op': 'subscribe', 'subscriptions': [subscription]}))
        samples = []
        while len(samples) < count:
            frame = await asyncio.wait_for(socket.recv(), TIMEOUT)
            if isinstance(frame, bytes) and frame[0] == 1:  # opcode 1: message data
                subscription_id, log_time = struct.unpack_from('<IQ', frame, 1)
                assert subscription_id == 7
                samples.append((log_time, frame[13:]))
        return channels, samples


def test_foxglove_client_decodes_supply_pressure_with_the_ros2msg_schema(renamed_valve):
    probe, port = renamed_valve
    channels, samples = asyncio.run(foxglove_samples(port, '/supply_pressure', 20))
    assert {topic: c['schemaName'] for topic, c in channels.items()} == PUBLISHED
    supply = channels['/supply_pressure']
    assert supply['encoding'] == 'cdr' and supply['schemaEncoding'] == 'ros2msg'
    schema = Schema(
        id=1, name=supply['schemaName'], encoding='ros2msg', data=supply['schema'].encode()
    )
    decode = DecoderFactory().decoder_for('cdr', schema)  # built from the advertised text only
    decoded = [decode(payload) for _, payload in samples]
    stamps = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in decoded]
    for (log_time, _), stamp, message in zip(samples, stamps, decoded):
        assert log_time == stamp and message.header.frame_id == f'{RENAMED}/supply_port'
    probe.wait_for(
        lambda: stamps[-1] in dict(probe.pressures['supply_pressure']), 'the same tick over DDS'
    )
    with probe.condition:
        over_dds = dict(probe.pressures['supply_pressure'])
    for stamp, message in zip(stamps, decoded):
        assert message.fluid_pressure == over_dds[stamp]  # the very value sent over DDS


def test_layout_parses_and_names_only_what_the_node_serves(renamed_valve):
    """Every topic and field the shipped Foxglove layout plots or shows exists."""
    _, port = renamed_valve
    layout = json.loads(layout_path().read_text())
    assert set(layout) >= {'configById', 'layout'}
    panels = layout['configById']
    paths = [path['value'] for config in panels.values() for path in config.get('paths', [])]
    topics = {path.split('.')[0] for path in paths} | {
        config['topicToRender'] for config in panels.values() if 'topicToRender' in config
    }
    advertised = asyncio.run(foxglove_samples(port, '/diagnostics', 0))[0]
    assert topics <= set(advertised) and topics <= set(PUBLISHED), topics
    assert '/diagnostics' in topics and len(paths) == 5
    for path in paths:  # /topic.field[.field][index]
        topic, *fields = path.split('.')
        message = message_class(PUBLISHED[topic])()
        for field in fields:
            name, index = re.fullmatch(r'(\w+)(?:\[(\d+)\])?', field).groups()
            assert name in message.get_fields_and_field_types(), path
            message = getattr(message, name)
        assert index is None or TOPIC_TYPES['joint_states'].endswith('JointState')
    layout_panels = json.dumps(layout['layout'])
    assert all(panel in layout_panels for panel in panels)


def test_layout_is_installed_with_the_package(tmp_path):
    """setup.py's data files put the layout in share/valve_sim/foxglove, as colcon would."""
    repo = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, 'setup.py', '-q', 'install_data', '--install-dir', str(tmp_path)],
        cwd=repo,
        capture_output=True,
        text=True,
        timeout=TIMEOUT,
    )
    assert done.returncode == 0, done.stderr
    installed = tmp_path / 'share' / 'valve_sim' / 'foxglove' / 'valve_layout.json'
    assert installed.read_bytes() == (repo / 'foxglove' / 'valve_layout.json').read_bytes()


def test_diagnostics_names_levels_and_hardware_id_after_a_rename(renamed_valve):
    probe, _ = renamed_valve
    assert probe.get_parameters('hardware_id', 'frame_prefix') == {
        'hardware_id': f'/{RENAMED}',  # the probe only keeps statuses with this hardware_id
        'frame_prefix': f'{RENAMED}/',
    }

    def fresh_until(condition, what):
        deadline = time.monotonic() + TIMEOUT
        with probe.condition:
            start = len(probe.diagnostics)
        while not any(condition(d) for d in probe.diagnostics[start:]):
            assert time.monotonic() < deadline, f'timed out waiting for {what}'
            probe.send_flow(INITIAL_FLOW)  # every 50 ms, inside the 0.5 s input timeout
            time.sleep(0.05)
        return next(d for d in probe.diagnostics[start:] if condition(d))

    ok = fresh_until(lambda d: d['level'] == DiagnosticStatus.OK[0], 'an OK status')
    assert ok['name'] == f'{RENAMED}: valve model'  # late ticks stay OK: named only
    stale = probe.wait_for_diagnostics(  # a skip under load is WARN too: wait for the input's
        lambda d: d['level'] == DiagnosticStatus.WARN[0] and 'input stale' in d['message'], 'WARN'
    )
    assert stale['name'] == ok['name']
    assert probe.set_parameters(max_inlet_flow=0.1)[0].successful
    probe.wait_for_new_samples(100)  # beyond the 20 ms trial window of that change
    probe.send_flow(0.05)  # 3000 L/min: an overpressure alarm, the model halts
    error = probe.wait_for_diagnostics(lambda d: d['level'] == DiagnosticStatus.ERROR[0], 'ERROR')
    assert error['name'] == ok['name'] and 'overpressure' in error['message']
    probe.send_flow(INITIAL_FLOW)
    probe.reset()


class AnalyserRun:
    """An analyser renamed to renamed_analyser in /analysed, and a replay there, spinning."""

    def __init__(self, context, output_dir, topics):
        self.analyser = analyser_node.ValveAnalyser(
            context=context,
            namespace='/analysed',
            cli_args=['--ros-args', '-r', '__node:=renamed_analyser'],
            parameter_overrides=[
                Parameter('output_dir', value=str(output_dir)),
                Parameter('bag_folder', value=True),
                Parameter('hardware_id', value='rig_7/recorder'),
                Parameter('topics', value=topics),
            ],
        )
        self.statuses, self.condition, self.measures = [], threading.Condition(), []
        self.analyser.status_publisher.publish = self._capture
        self.analyser.measures_publisher.publish = self.measures.append
        self.source = rclpy.create_node('replay', namespace='/analysed', context=context)
        self.replay = Replay(self.source)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=context)
        for node in (self.analyser, self.source):
            self.executor.add_node(node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _capture(self, array):
        with self.condition:
            self.statuses.extend(array.status)
            self.condition.notify_all()

    def wait_for(self, level, text):
        """Return the first recording status of level whose message has text (waits)."""
        deadline = time.monotonic() + TIMEOUT

        def found():
            return next((s for s in self.statuses if s.level[0] == level and text in s.message), 0)

        with self.condition:
            while not found():
                assert time.monotonic() < deadline, f'no status {level} "{text}"'
                self.condition.wait(1.0)
            return found()

    def close(self):
        self.executor.shutdown()
        self.thread.join(TIMEOUT)
        self.analyser.close()
        self.analyser.destroy_node()
        self.source.destroy_node()


def test_analyser_names_levels_and_hardware_id_after_a_rename(context, tmp_path, monkeypatch):
    from rosbags.rosbag2 import Reader

    run = AnalyserRun(context, tmp_path, list(TICK_TOPICS))
    try:
        waiting = run.wait_for(DiagnosticStatus.WARN[0], 'no messages yet')
        assert waiting.name == 'renamed_analyser: recording'
        assert waiting.hardware_id == 'rig_7/recorder'
        run.replay.wait_for_subscribers(timeout=TIMEOUT)
        waveforms = simulate(load_parameters().params, FlowStep(step_time=0.05, end_time=0.2))
        relief = relief_flows(load_parameters().params, waveforms)
        run.replay.publish(waveforms, time.time_ns(), every=10, relief=relief)
        recording = run.wait_for(DiagnosticStatus.OK[0], 'recording to')
        assert (recording.name, recording.hardware_id) == (waiting.name, waiting.hardware_id)
    finally:
        run.close()
    (measured,) = [status for array in run.measures for status in array.status]
    assert measured.name == 'renamed_analyser: step measures'  # measured on closing
    assert measured.hardware_id == 'rig_7/recorder'
    folder = run.analyser.bag.folder  # a rosbag2 bag folder, read by rosbags
    assert folder.parent == tmp_path and (folder / 'metadata.yaml').is_file()
    with Reader(folder) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts == {f'/analysed/{topic}': n for topic, n in run.replay.published.items()}
        offer = reader.connections[0].ext.offered_qos_profiles[0]  # as DDS reports the offer
        assert offer.reliability.name == 'RELIABLE' and offer.history.name == 'UNKNOWN'
        assert reader.storage.metadata.custom == {
            'recorded_by': 'valve_sim analyser_node rig_7/recorder'
        }

    real_message_class = recorder.message_class

    def message_class_without_string(type_name):  # a type this analyser has no package for
        if type_name == 'std_msgs/msg/String':
            raise ImportError('no module named std_msgs (test)')
        return real_message_class(type_name)

    monkeypatch.setattr(recorder, 'message_class', message_class_without_string)
    run = AnalyserRun(context, tmp_path, ['mystery', 'quiet'])
    try:
        run.source.create_publisher(message_class('std_msgs/msg/Float64'), 'quiet', 10)
        run.wait_for(DiagnosticStatus.WARN[0], 'no messages yet on /analysed/mystery')
        string = message_class('std_msgs/msg/String')
        run.source.create_publisher(string, 'mystery', 10).publish(string(data='?'))
        error = run.wait_for(DiagnosticStatus.ERROR[0], 'cannot record /analysed/mystery')
        assert (error.name, error.hardware_id) == (waiting.name, waiting.hardware_id)
    finally:
        run.close()
    with Reader(run.analyser.bag.folder) as reader:  # subscribed, silent: listed, as in rosbag2
        counts = {c.topic: c.msgcount for c in reader.connections}
    # quiet, and the analysed signals (always wanted) of the replay's silent publishers
    assert counts == dict.fromkeys(
        ['/analysed/quiet', '/analysed/applied_inlet_flow', '/analysed/joint_states',
         '/analysed/supply_pressure', '/analysed/applied_tank_pressure'], 0
    )
