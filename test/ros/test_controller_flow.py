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
`valve-sim scenario run --flow-topic`: a controller under test supplies the valve's flow.

A small controller node answers each state of valve_node (applied_inlet_flow, stamped
t_k) with the flow for the tick from t_k, stamped t_k (sensor_msgs/JointState,
velocity[0]); each tick must apply exactly its reply, one /clock per tick, whatever
the load: the runner waits for the reply stamped for the tick, sends it stamped, and
valve_node waits for it (the lockstep protocol).
"""

import threading

import numpy as np
import pytest
import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from valve_sim.analysis.scenarios.bench_scenario import load_scenario
from valve_sim.core.errors import IncompleteRunError
from valve_sim.core.flow_step import LITRE_PER_MINUTE as L_PER_MIN
from valve_sim.recording.tick_bags import bag_column
from valve_sim.ros.lockstep import NS_PER_S, START_NS
from valve_sim.ros.scenario_runner import run_scenario


pytestmark = pytest.mark.usefixtures('valve_node_kernels')  # compiled before a start
SCENARIO = ('scenario: controlled\nduration: 0.2\ninputs:\n  inlet_flow:\n'
            '    initial: 5 L/min\nexpect:\n  - no_alarm: {}\n')
PERIOD_NS = 1_000_000  # the default publish_rate's tick
QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def controller_flow(tick):
    """Return the controller's flow for the tick from tick k's state [m^3/s]: its own ramp."""
    return (5.0 + 0.05 * tick) * L_PER_MIN


class Controller:
    """A use_sim_time node that answers each valve state with a stamped flow, in a thread."""

    def __init__(self, topic, misstamp=None):
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('controller', context=self.context,
                                      parameter_overrides=[rclpy.Parameter('use_sim_time',
                                                                           value=True)])
        self.misstamp = misstamp  # a tick whose reply it stamps 1 ns late
        self.publisher = self.node.create_publisher(JointState, topic, QOS)
        self.node.create_subscription(JointState, 'applied_inlet_flow', self._answer, QOS)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _answer(self, state):
        stamp = state.header.stamp
        tick = (stamp.sec * NS_PER_S + stamp.nanosec - START_NS) // PERIOD_NS
        if tick == self.misstamp:
            state.header.stamp.nanosec += 1
        self.publisher.publish(JointState(header=state.header, name=['inlet_flow'],
                                          velocity=[controller_flow(tick)]))

    def _spin(self):
        try:
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)
        except ExternalShutdownException:  # close() shut the context down meanwhile
            pass

    def close(self):
        self.context.try_shutdown()
        self.thread.join()


@pytest.fixture
def scenario(tmp_path):
    (tmp_path / 'run').mkdir()
    (tmp_path / 'controlled.yaml').write_text(SCENARIO)
    return load_scenario(tmp_path / 'controlled.yaml', bag_column)


def test_each_tick_applies_the_controller_s_reply_stamped_for_it(tmp_path, scenario):
    controller = Controller('controller_flow')
    try:
        record = run_scenario(scenario, tmp_path / 'run', progress=lambda line: None,
                              flow_topic='controller_flow')
    finally:
        controller.close()
    ticks = np.arange(scenario.ticks)
    expected = [5 * L_PER_MIN] + [controller_flow(tick) for tick in ticks[1:]]
    assert record.flows[:scenario.ticks].tolist() == expected  # sent: the replies
    # the bag: the state after tick k applied flows[k] (check_complete checked each float)
    assert record.series['inlet_flow'][1:].tolist() == expected
    assert record.clock_steps == scenario.ticks  # one /clock a tick: it answers each state
    assert record.passed


def test_a_reply_stamped_for_no_tick_ends_the_run_naming_the_tick(tmp_path, scenario):
    controller = Controller('controller_flow', misstamp=50)
    try:
        with pytest.raises(IncompleteRunError, match='no flow reply .* stamped 1.050000 s'):
            run_scenario(scenario, tmp_path / 'run', progress=lambda line: None,
                         flow_topic='controller_flow')
    finally:
        controller.close()
