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
valve_node's lockstep inputs: stamped with the model time they apply from, never raced by /clock.

An input message and the /clock of the tick it is meant for travel on different topics,
and nothing orders them: under load the tick could come first and apply the value
before. With the read-only parameter lockstep_inputs ('inlet_flow', 'tank_pressure',
or both, comma-separated) the node takes those inputs stamped instead: the inlet flow
as sensor_msgs/JointState on inlet_flow_stamped (velocity[0] [m^3/s]), the tank
pressure as sensor_msgs/FluidPressure on tank_pressure, each header.stamp the model
time the value holds from. The tick from t_k to t_k+1 does not start until a message
of each such input stamped later than t_k has been taken (settle): it then applies
the value stamped last at or before t_k (of two with one stamp, the later sent).
Messages of one publisher on one topic arrive in order (reliable, keep last
QUEUE_DEPTH), so a later stamp proves that every value for t_k was taken. A driver
thus publishes the values of a batch of ticks, each stamped with its tick's start,
then the value held stamped with the batch's end (the cover), then one /clock for the
whole batch (ros.lockstep).
Waiting blocks the tick (valve_node runs no other callbacks meanwhile: in lockstep
the driver waits for the tick anyway) for at most WAIT_TIMEOUT; then the tick applies
the value held, counted and logged, and the driver reports the difference.
"""

import time

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from valve_sim.core.errors import ParameterError
from valve_sim.ros.raw_take import RawTaker
from valve_sim.ros.valve_inputs import STAMPED_FLOW_TOPIC


PARAMETER = 'lockstep_inputs'
INPUT_NAMES = ('inlet_flow', 'tank_pressure')
QUEUE_DEPTH = 10_000  # a driver's batch never comes near it: nothing is dropped
QOS = QoSProfile(depth=QUEUE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
WAIT_TIMEOUT = 30.0  # [s] for a tick's stamped input, past any load a run survives
WAIT_SLICE_NS = 100_000_000  # [ns] one wait, between checks that the node still runs
DESCRIPTION = (
    'inputs a lockstep driver sends stamped with the model time they apply from: '
    "'inlet_flow' (sensor_msgs/JointState on inlet_flow_stamped), 'tank_pressure', "
    "or both, comma-separated; a tick on /clock waits for them (default '': none)"
)


def declare_lockstep_inputs(node):
    """Declare lockstep_inputs (read-only); return the input names it gives."""
    descriptor = ParameterDescriptor(name=PARAMETER, description=DESCRIPTION, read_only=True)
    text = node.declare_parameter(PARAMETER, '', descriptor).value
    names = [name.strip() for name in text.split(',') if name.strip()]
    unknown = sorted(set(names) - set(INPUT_NAMES))
    if unknown:
        raise ParameterError(f"{PARAMETER}: unknown input {', '.join(unknown)} "
                             f"(inputs: {', '.join(INPUT_NAMES)})")
    return names


class LockstepInputs:
    """
    The node's stamped inputs, each (CheckedInput, subscription, taker), and their waits.

    flow_input, tank_input: the node's InletFlowInput and TankPressureInput, put in
    lockstep mode if named; tank_subscription: a callable creating the tank_pressure
    subscription of a QoS (the node's, made reliable and deep here in lockstep).
    late: the ticks that started without their input within WAIT_TIMEOUT.
    """

    def __init__(self, node, names, flow_input, tank_input):
        self.node, self.names, self.inputs, self.late = node, names, [], 0
        self.subscriptions = []
        if 'inlet_flow' in names:
            flow_input.lockstep()
            subscription = node.create_subscription(
                JointState, STAMPED_FLOW_TOPIC, lambda _: None, QOS, raw=True)
            self._add(flow_input, subscription, RawTaker(flow_input.receive_stamped))
        self.tank_input = tank_input if 'tank_pressure' in names else None
        if self.tank_input is not None:
            tank_input.lockstep()

    def _add(self, checked, subscription, taker):
        self.inputs.append((checked, subscription, taker))
        self.subscriptions.append(subscription)

    def tank_qos(self, qos):
        """Return the tank_pressure subscription's QoS: reliable and deep in lockstep."""
        return QOS if self.tank_input is not None else qos

    def add_tank_subscription(self, subscription):
        """Wait for the node's tank_pressure subscription too, taken by tank_input itself."""
        if self.tank_input is not None:
            self._add(self.tank_input, subscription, self.tank_input)

    def settle(self, time_ns, on_clock=True):
        """
        Before the tick starting at time_ns [ns]: wait for each input's value there, hold it.

        Returns at once when every input has a message stamped later than time_ns;
        otherwise takes and waits for at most WAIT_TIMEOUT in all. Off /clock
        (on_clock False: no driver steps the time) it takes what came, waits for none.
        """
        deadline = None
        for checked, subscription, taker in self.inputs:
            if not on_clock:
                taker.take(subscription)
            while on_clock and not checked.covers(time_ns):
                if taker.take(subscription):
                    continue
                deadline = deadline or time.monotonic() + WAIT_TIMEOUT
                if time.monotonic() > deadline or not self.node.context.ok():
                    self._report_late(subscription.topic_name, time_ns)
                    break
                wait(self.node.context, subscription)
            checked.hold_at(time_ns)

    def _report_late(self, topic, time_ns):
        self.late += 1
        self.node.get_logger().error(
            f'lockstep: no message on {topic} stamped after {time_ns / 1e9:.6f} s '
            f'within {WAIT_TIMEOUT:g} s; the tick applies the value held (late inputs: '
            f'{self.late})')


def wait(context, subscription):
    """Wait until subscription has a message, or WAIT_SLICE_NS passed."""
    wait_set = _rclpy.WaitSet(1, 0, 0, 0, 0, 0, context.handle)
    with subscription.handle:
        wait_set.clear_entities()
        wait_set.add_subscription(subscription.handle)
        wait_set.wait(WAIT_SLICE_NS)
