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
analyser_node's ~/restart (valve_sim.ros.analyser_restart), on a node of the test process.

The recording before a restart closed complete, the new one from the restart on, the
parameters as if launched with the request's too, and refused requests changing nothing.
"""

import json
import time

from mcap.reader import make_reader
from rcl_interfaces.srv import SetParametersAtomically
import rclpy
from rclpy.parameter import Parameter
from std_msgs.msg import Float64
from valve_sim.core.catalogue import STANDARD_ATMOSPHERE
from valve_sim.recording.bag import BagReader
from valve_sim.recording.cdr import read_message
from valve_sim.ros import analyser_restart
from valve_sim.ros.analyser_node import ValveAnalyser


TIMEOUT = 60.0  # [s] for discovery and delivery on a loaded machine


def flows(bag):
    """Return the /inlet_flow values recorded in bag, in order."""
    return [read_message('std_msgs/msg/Float64', message.data).data
            for _, _, message in BagReader(bag).messages({'/inlet_flow'})]


def test_a_restart_closes_the_recording_and_records_anew_and_a_refused_one_changes_nothing(
        context, node, tmp_path, monkeypatch):
    # a repeated request is told from a new one by time: none here is meant as a repeat
    # but the last, however slowly a loaded machine runs the test
    monkeypatch.setattr(analyser_restart, 'REPEAT_WINDOW', float('inf'))
    first, second = tmp_path / 'first', tmp_path / 'second'
    analyser = ValveAnalyser(context=context, parameter_overrides=[
        Parameter('output_dir', value=str(first)), Parameter('drain_period', value=0.01)])
    client = node.create_client(SetParametersAtomically, '/valve_analyser/restart')
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(analyser)
    executor.add_node(node)

    def spin_until(condition, what):
        deadline = time.monotonic() + TIMEOUT
        while not condition():
            assert time.monotonic() < deadline, f'no {what} within {TIMEOUT} s'
            executor.spin_once(timeout_sec=0.01)

    def recorded():
        topic = analyser.recorder.recorded.get('/inlet_flow')
        return topic.count if topic else 0

    def send(values):
        """Publish values on /inlet_flow; wait until the analyser has recorded them all."""
        # a new publisher: matched only by the recording's own subscription, never by the
        # one a restart destroyed
        publisher = node.create_publisher(Float64, 'inlet_flow', 10)
        spin_until(lambda: '/inlet_flow' in analyser.recorder.recorded
                   and publisher.get_subscription_count() > 0, 'subscription to /inlet_flow')
        before = recorded()
        for value in values:
            publisher.publish(Float64(data=value))
        spin_until(lambda: recorded() == before + len(values), 'recorded /inlet_flow')
        node.destroy_publisher(publisher)

    def restart(**overrides):
        spin_until(client.service_is_ready, 'service ~/restart')
        future = client.call_async(SetParametersAtomically.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg()
            for name, value in overrides.items()]))
        spin_until(future.done, 'answer to ~/restart')
        return future.result().result

    try:
        send([1.0, 2.0, 3.0])
        old = analyser.bag.path
        result = restart(output_dir=str(second), ambient_pressure=90e3)
        assert result.successful, result.reason
        # the old recording closed as at shutdown: summary written, every message in it
        with open(old, 'rb') as stream:
            assert make_reader(stream).get_summary() is not None
        assert flows(old) == [1.0, 2.0, 3.0]
        assert json.loads(old.with_suffix('.measures.json').read_text())['steps'] == []
        # the new one, in the request's folder, as if launched with its parameters too
        assert analyser.bag.path.parent == second and analyser.bag.path != old
        assert analyser.get_parameter('output_dir').value == str(second)
        assert analyser.get_parameter('ambient_pressure').value == 90e3
        assert analyser.get_parameter('drain_period').value == 0.01  # the start-up value
        send([4.0, 5.0])
        new = analyser.bag.path
        for refused in ({'no_such_parameter': 1.0}, {'queue_depth': 5},
                        {'ambient_pressure': 'high'}, {'topics': [1, 2]},
                        {'use_sim_time': True}, {'output_dir': str(old)}):  # a file
            result = restart(**refused)
            assert not result.successful and 'nothing changed' in result.reason, refused
            assert analyser.bag.path == new, refused
            assert analyser.get_parameter('output_dir').value == str(second)
            assert analyser.get_parameter('ambient_pressure').value == 90e3
        send([6.0])
        result = restart()  # over the start-up values, not over the last restart's
        assert result.successful, result.reason
        assert analyser.bag.path.parent == first
        assert analyser.get_parameter('ambient_pressure').value == STANDARD_ATMOSPHERE
        send([7.0])
        latest = analyser.bag.path
        repeat = restart()  # its client asking again for a lost answer: no second bag
        assert repeat.successful and repeat.reason == result.reason
        assert analyser.bag.path == latest
    finally:
        analyser.close()
        executor.shutdown()
        analyser.destroy_node()
        node.destroy_client(client)
    assert flows(new) == [4.0, 5.0, 6.0]
    assert flows(analyser.bag.path) == [7.0]
    assert sorted(first.glob('*.mcap')) == sorted([old, analyser.bag.path])
