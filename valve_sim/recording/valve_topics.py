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
valve_node's topics and messages, for writing offline runs as bags and for test publishers.

The layout (names relative, types, contents) is valve_node's wire interface:
each tick publishes the four chamber pressures as sensor_msgs/msg/FluidPressure
in absolute Pa (model gauge pressure + ambient_pressure), joint_states
(main_valve, pilot_poppet: position [m], velocity [m/s]), applied_inlet_flow
(inlet_flow: velocity = the inlet flow [m^3/s] applied over the interval ending at
the stamp), applied_tank_pressure (FluidPressure, absolute Pa: the tank pressure
applied over that interval) and relief_flow (sensor_msgs/msg/JointState, velocity of
relief_flow = all the valve passes to the tank [m^3/s] at the stamp's state, and of
its parts main_stage, pilot_stage, seat_leakage), all stamped with the model time.
The commands are inlet_flow, std_msgs/msg/Float64 [m^3/s], and tank_pressure,
sensor_msgs/msg/FluidPressure (absolute Pa).

Frames: each pressure is measured at a place of the valve, its header.frame_id
frame_prefix + PRESSURE_FRAMES[topic] (valve_node's frame_prefix parameter, by
default its node name and '/'), so a user can place each sensor in TF. The joint
states carry no frame (frame_id ''), as joint_state_publisher's do.
"""

import importlib
import time

import numpy as np
from sensor_msgs.msg import FluidPressure
from std_msgs.msg import Float64
from valve_sim.core.errors import ParameterError
from valve_sim.core.model import P_C, P_S, STATE_NAMES, X, X_DOT, Y, Y_DOT
from valve_sim.core.parameters import NODE_NAME, STANDARD_ATMOSPHERE
from valve_sim.recording.cdr import CdrMessage


PRESSURE_TOPICS = STATE_NAMES[P_S:P_C + 1]
TICK_TOPICS = PRESSURE_TOPICS + (
    'joint_states', 'applied_inlet_flow', 'applied_tank_pressure', 'relief_flow'
)
JOINT_NAMES = ('main_valve', 'pilot_poppet')  # joint_states: x and y
# relief_flow's joints: the whole flow to the tank, then its parts (simulation.RELIEF_COLUMNS)
RELIEF_JOINTS = ('relief_flow', 'main_stage', 'pilot_stage', 'seat_leakage')
TOPIC_TYPES = {
    **dict.fromkeys(PRESSURE_TOPICS, 'sensor_msgs/msg/FluidPressure'),
    'joint_states': 'sensor_msgs/msg/JointState',
    'applied_inlet_flow': 'sensor_msgs/msg/JointState',
    'applied_tank_pressure': 'sensor_msgs/msg/FluidPressure',
    'relief_flow': 'sensor_msgs/msg/JointState',
    'inlet_flow': 'std_msgs/msg/Float64',
    'inlet_flow_stamped': 'sensor_msgs/msg/JointState',  # lockstep (ros.lockstep_inputs)
    'tank_pressure': 'sensor_msgs/msg/FluidPressure',
}
# Every node's parameter changes (rclpy publishes them): valve_node's end a step's window
PARAMETER_EVENTS_TOPIC = '/parameter_events'
PARAMETER_EVENT = 'rcl_interfaces/msg/ParameterEvent'
PRESSURE_FRAMES = dict(  # where each pressure is measured
    zip(
        PRESSURE_TOPICS,
        ('supply_port', 'intermediate_chamber', 'pilot_chamber', 'poppet_chamber'),
    )
)
TANK_FRAME = 'tank_port'  # applied_tank_pressure's place (and an offline bag's tank_pressure)
DEFAULT_FRAME_PREFIX = NODE_NAME + '/'
NS_PER_S = 1_000_000_000
TICK_INTERVAL = 1e-3  # [s] valve_node's default tick (publish_rate 1 kHz)
# Receive time - send time of an offline bag's messages: one hop of the bench's bare echo
# round trip on this machine (p50 0.66 ms, p99 1.56 ms, docs/valve_node.md) is 0.33 ms
# (p50); modelled as a fixed part plus an exponential jitter, capped so that each
# topic's messages still arrive in order (ticks are 1 ms apart). Seeded: same bag each run.
TRANSPORT_DELAY_NS = 250_000  # [ns] fixed part
TRANSPORT_JITTER_NS = 100_000  # [ns] mean of the exponential part
TRANSPORT_JITTER_CAP_NS = 500_000  # [ns]
TRANSPORT_SEED = 14


def message_class(type_name):
    """Return the Python class of a message type 'pkg/msg/Type'."""
    package, namespace, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.{namespace}'), name)


class TickMessages:
    """
    The serialized messages of one valve_node tick, built once and refilled every tick.

    fill() writes the state (8 model states, SI, gauge pressures) at time_ns [ns]
    into them and returns [(topic, CDR bytes)]. valve_node publishes these; the
    offline bag writer and the replay publisher write them: one layout for all.
    A pressure's header.frame_id is frame_prefix + its PRESSURE_FRAMES name
    (applied_tank_pressure's: + TANK_FRAME).
    """

    def __init__(self, frame_prefix=DEFAULT_FRAME_PREFIX):
        self._messages = []
        self._pressure_offsets = []
        for name in PRESSURE_TOPICS:  # sensor_msgs/FluidPressure
            message = CdrMessage(frame_id=frame_prefix + PRESSURE_FRAMES[name])
            self._pressure_offsets.append(message.float64())  # fluid_pressure
            message.float64()  # variance: 0, unknown
            self._messages.append((name, message))
        self._joints = CdrMessage(frame_id='')  # sensor_msgs/JointState
        self._joints.strings(JOINT_NAMES)
        self._joint_positions = self._joints.float64s(len(JOINT_NAMES))
        self._joint_velocities = self._joints.float64s(len(JOINT_NAMES))
        self._joints.float64s(0)  # effort
        self._applied = CdrMessage(frame_id='')
        self._applied.strings(['inlet_flow'])
        self._applied.float64s(0)  # position
        self._applied_velocity = self._applied.float64s(1)
        self._applied.float64s(0)  # effort
        self._tank = CdrMessage(frame_id=frame_prefix + TANK_FRAME)  # FluidPressure
        self._tank_offset = self._tank.float64()
        self._tank.float64()  # variance: 0, unknown
        self._relief = CdrMessage(frame_id='')  # sensor_msgs/JointState
        self._relief.strings(RELIEF_JOINTS)
        self._relief.float64s(0)  # position
        self._relief_velocity = self._relief.float64s(len(RELIEF_JOINTS))
        self._relief.float64s(0)  # effort
        self._messages += [
            ('joint_states', self._joints),
            ('applied_inlet_flow', self._applied),
            ('applied_tank_pressure', self._tank),
            ('relief_flow', self._relief),
        ]

    def fill(
        self, time_ns, state, applied_flow, ambient_pressure, readings=None, tank_pressure=0.0,
        relief=None,
    ):
        """
        Return the tick's [(topic, CDR bytes)]; applied_flow [m^3/s], ambient_pressure [Pa].

        readings: the published pressures [Pa absolute] (a sensor stage's), nan for a
        topic that publishes nothing; default: the state's pressures + ambient_pressure.
        tank_pressure: the applied tank pressure [Pa, gauge]. relief: the relief flow
        and its parts [m^3/s] (RELIEF_JOINTS); None: relief_flow publishes nothing.
        """
        if readings is None:
            readings = [pressure + ambient_pressure for pressure in state[P_S:P_C + 1]]
        for (_, message), offset, reading in zip(
            self._messages, self._pressure_offsets, readings
        ):
            if reading == reading:  # not nan
                message.set_float64s(offset, reading)
        self._joints.set_float64s(self._joint_positions, state[X], state[Y])
        self._joints.set_float64s(self._joint_velocities, state[X_DOT], state[Y_DOT])
        self._applied.set_float64s(self._applied_velocity, applied_flow)
        self._tank.set_float64s(self._tank_offset, tank_pressure + ambient_pressure)
        if relief is not None:
            self._relief.set_float64s(self._relief_velocity, *relief)
        sec, nanosec = divmod(time_ns, NS_PER_S)
        tick = []
        for index, (topic, message) in enumerate(self._messages):
            if index < len(readings) and readings[index] != readings[index]:
                continue  # nan: this topic publishes nothing
            if message is self._relief and relief is None:
                continue
            message.set_stamp(sec, nanosec)
            tick.append((topic, message.bytes()))
        return tick


def transport_delays(count, seed=TRANSPORT_SEED):
    """Return count receive - send delays [ns] of the offline bag's transport model (seeded)."""
    jitter = np.random.default_rng(seed).exponential(TRANSPORT_JITTER_NS, count)
    return TRANSPORT_DELAY_NS + np.minimum(jitter, TRANSPORT_JITTER_CAP_NS).astype(np.int64)


def publish_interval_for(record_interval):
    """
    Return the interval [s] an offline bag publishes at, for waveforms sampled this often.

    valve_node's 1 kHz ticks (TICK_INTERVAL) where they are a whole number of samples,
    else every sample (a record interval coarser than 1 ms, or not a divisor of it).
    """
    ratio = TICK_INTERVAL / record_interval
    return TICK_INTERVAL if abs(ratio - round(ratio)) < 1e-9 and ratio >= 1 else record_interval


def samples_per_publish(waveforms, publish_interval):
    """Return the number of waveform samples in one publish_interval [s] (a whole number)."""
    record_interval = waveforms.time[1] - waveforms.time[0]
    every = round(publish_interval / record_interval)
    if every < 1 or abs(every * record_interval - publish_interval) > 1e-9 * publish_interval:
        raise ParameterError(
            f'publish interval {publish_interval:g} s is not a whole multiple of the '
            f"waveforms' sample interval {record_interval:g} s"
        )
    return every


def start_ns(start_time_ns=None):
    """Return start_time_ns [ns since the epoch], or for None the time now, to the millisecond."""
    if start_time_ns is None:
        return time.time_ns() // 1_000_000 * 1_000_000
    return start_time_ns


def write_simulation_bag(
    path,
    waveforms,
    ambient_pressure=STANDARD_ATMOSPHERE,
    publish_interval=1e-3,
    *,
    start_time_ns=None,
    folder=False,
    frame_prefix=DEFAULT_FRAME_PREFIX,
    readings=None,
    namespace='',
    relief=None,
):
    """
    Write an offline run as the MCAP bag valve_node and the analyser would have recorded.

    waveforms: simulation.Waveforms; every sample publish_interval [s] apart (a
    whole multiple of the waveforms' sample interval) becomes one tick, stamped
    start_time_ns [ns since the epoch; None: now, start_ns()] + its model time, sent
    (publish_time) at its stamp. inlet_flow carries the command: the first flow at the
    start and each change at the last tick before it was applied; tank_pressure likewise, where the
    run's tank was not at ambient throughout (absolute: + ambient_pressure). relief:
    the relief flow and its parts per sample (simulation.relief_flows; None: no
    relief_flow messages). Each message is received
    (log_time) after a transport delay (transport_delays()). folder: write a
    rosbag2 bag folder at path instead of a file. readings: the pressure topics'
    values per tick [Pa absolute] (sensors.read_waveforms; nan: nothing published);
    default: the model's pressures + ambient_pressure. namespace: the node's ('/rig1'),
    its topics below it; '' the root. Returns the number of ticks written; raises
    ParameterError for a bad interval.
    """
    from valve_sim.recording.bag import BagWriter  # here: valve_node needs no MCAP library

    every = samples_per_publish(waveforms, publish_interval)
    start_time_ns = start_ns(start_time_ns)
    bag = BagWriter(
        path, folder=folder, custom_data={'source': 'valve-sim simulate (offline model run)'}
    )
    tick = TickMessages(frame_prefix)
    indices = range(0, len(waveforms.time), every)
    delays = iter(transport_delays(len(indices) * (len(TICK_TOPICS) + 2)).tolist())
    try:
        prefix = namespace.rstrip('/') + '/'
        tanks = waveforms.tank_pressure
        tanks = np.zeros(len(waveforms.time)) if tanks is None else tanks
        commanded, commanded_tank, tank_commands = None, None, bool(np.any(tanks != 0.0))
        # As a recording of valve_node: a topic nobody published is not in the bag (the
        # flow comes on inlet_flow, as from a free-running bench, not on lockstep's topic).
        unwritten = {'inlet_flow_stamped'} | ({'tank_pressure'} if not tank_commands else set())
        unwritten |= {'relief_flow'} if relief is None else set()
        for topic, type_name in TOPIC_TYPES.items():
            if topic not in unwritten:
                bag.add_topic(prefix + topic, type_name)
        for row, (previous, index) in enumerate(zip([None, *indices], indices)):
            time_ns = start_time_ns + round(waveforms.time[index] * NS_PER_S)
            command_ns = (
                time_ns
                if previous is None
                else start_time_ns + round(waveforms.time[previous] * NS_PER_S)
            )
            flow, tank = float(waveforms.inlet_flow[index]), float(tanks[index])
            if flow != commanded:
                bag.write_message(
                    prefix + 'inlet_flow', Float64(data=flow), command_ns + next(delays),
                    command_ns,
                )
                commanded = flow
            if tank_commands and tank != commanded_tank:
                message = FluidPressure(fluid_pressure=tank + ambient_pressure)
                message.header.stamp.sec, message.header.stamp.nanosec = divmod(
                    command_ns, NS_PER_S
                )
                message.header.frame_id = frame_prefix + TANK_FRAME
                bag.write_message(
                    prefix + 'tank_pressure', message, command_ns + next(delays), command_ns
                )
                commanded_tank = tank
            published = None if readings is None else readings[row].tolist()
            for topic, data in tick.fill(
                time_ns, waveforms.states[index], flow, ambient_pressure, published, tank,
                None if relief is None else relief[index].tolist(),
            ):
                bag.write(bag.channels[prefix + topic], data, time_ns + next(delays), time_ns)
        return len(indices)
    finally:
        bag.close()


def write_rig_bag(
    path,
    waveforms,
    pressure_topic,
    flow_topic,
    ambient_pressure=STANDARD_ATMOSPHERE,
    pressure_noise=0.0,
    seed=0,
    publish_interval=1e-3,
    *,
    start_time_ns=None,
    folder=False,
    flow_interval=None,
):
    """
    Write an offline run as a test rig records it: two std_msgs/msg/Float64 topics.

    pressure_topic: supply pressure [Pa absolute: gauge + ambient_pressure] every
    publish_interval [s], with Gaussian noise of standard deviation pressure_noise [Pa]
    (generator seeded with seed); flow_topic: the inlet flow [m^3/s] over the interval
    ending at each sample, as a flow meter reports it, every flow_interval [s] (default
    publish_interval; a whole multiple of the waveforms' interval). No main-valve
    position, no headers: the receive time (log_time) is the sample time,
    start_time_ns [ns since the epoch; None: now, start_ns()] + the model time.
    folder: a rosbag2 bag folder at path. Returns the number of pressure samples.
    """
    from valve_sim.recording.bag import BagWriter

    every = samples_per_publish(waveforms, publish_interval)
    flow_every = samples_per_publish(waveforms, flow_interval or publish_interval)
    start_time_ns = start_ns(start_time_ns)
    indices = np.arange(0, len(waveforms.time), every)
    noise = np.random.default_rng(seed).normal(0.0, pressure_noise, len(indices))
    pressure = waveforms.states[indices, P_S] + ambient_pressure + noise
    bag = BagWriter(
        path, folder=folder, custom_data={'source': 'valve-sim simulate --rig-topics (offline)'}
    )
    try:
        for topic in (pressure_topic, flow_topic):
            bag.add_topic(topic, 'std_msgs/msg/Float64')
        flows = set(range(0, len(waveforms.time), flow_every))
        for index in sorted(flows | set(indices.tolist())):  # in time order, pressure first
            time_ns = start_time_ns + round(waveforms.time[index] * NS_PER_S)
            if index % every == 0:
                value = float(pressure[index // every])
                bag.write_message(pressure_topic, Float64(data=value), time_ns, time_ns)
            if index in flows:
                flow = float(waveforms.inlet_flow[index])
                bag.write_message(flow_topic, Float64(data=flow), time_ns, time_ns)
        return len(indices)
    finally:
        bag.close()
