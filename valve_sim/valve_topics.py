"""valve_node's topics and messages, for writing offline runs as bags and for test publishers.

The layout (names relative, types, contents) is valve_node's wire interface:
each tick publishes the four chamber pressures as sensor_msgs/msg/FluidPressure
in absolute Pa (model gauge pressure + ambient_pressure), joint_states
(main_valve, pilot_poppet: position [m], velocity [m/s]) and applied_inlet_flow
(inlet_flow: velocity = the inlet flow [m^3/s] applied over the interval ending at
the stamp), all stamped with the model time. The inlet_flow command is
std_msgs/msg/Float64 [m^3/s].
"""
import importlib

from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64

from valve_sim.bag import BagWriter
from valve_sim.model import P_C, P_S, STATE_NAMES, X, X_DOT, Y, Y_DOT
from valve_sim.parameters import STANDARD_ATMOSPHERE, ParameterError

PRESSURE_TOPICS = STATE_NAMES[P_S:P_C + 1]
TICK_TOPICS = PRESSURE_TOPICS + ("joint_states", "applied_inlet_flow")
TOPIC_TYPES = {
    **{name: "sensor_msgs/msg/FluidPressure" for name in PRESSURE_TOPICS},
    "joint_states": "sensor_msgs/msg/JointState",
    "applied_inlet_flow": "sensor_msgs/msg/JointState",
    "inlet_flow": "std_msgs/msg/Float64",
}
NS_PER_S = 1_000_000_000


def message_class(type_name):
    """The Python class of a message type 'pkg/msg/Type'."""
    package, namespace, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{namespace}"), name)


class TickMessages:
    """The messages of one valve_node tick, allocated once and refilled every tick.

    fill() writes the state (8 model states, SI, gauge pressures) at time_ns [ns]
    into them and returns [(topic, message)]. valve_node publishes these; the
    offline bag writer and the replay publisher write them: one layout for all.
    """

    def __init__(self):
        self._messages = []
        for name in PRESSURE_TOPICS:
            message = FluidPressure(variance=0.0)
            message.header.frame_id = name
            self._messages.append((name, message))
        self._joints = JointState(name=["main_valve", "pilot_poppet"])
        self._joints.header.frame_id = "joint_states"
        self._applied = JointState(name=["inlet_flow"])
        self._applied.header.frame_id = "applied_inlet_flow"
        self._messages += [("joint_states", self._joints), ("applied_inlet_flow", self._applied)]

    def fill(self, time_ns, state, applied_flow, ambient_pressure):
        """The tick's [(topic, message)]; applied_flow [m^3/s], ambient_pressure [Pa]."""
        for index in range(len(PRESSURE_TOPICS)):
            self._messages[index][1].fluid_pressure = float(state[index]) + ambient_pressure
        self._joints.position = [float(state[X]), float(state[Y])]
        self._joints.velocity = [float(state[X_DOT]), float(state[Y_DOT])]
        self._applied.velocity = [float(applied_flow)]
        sec, nanosec = divmod(time_ns, NS_PER_S)
        for _, message in self._messages:
            message.header.stamp.sec, message.header.stamp.nanosec = sec, nanosec
        return self._messages


def write_simulation_bag(path, waveforms, ambient_pressure=STANDARD_ATMOSPHERE, publish_interval=1e-3, start_time_ns=0):
    """Write an offline run as the MCAP bag valve_node and the analyser would have recorded.

    waveforms: simulation.Waveforms; every sample publish_interval [s] apart (a
    whole multiple of the waveforms' sample interval) becomes one tick, stamped
    start_time_ns [ns] + its model time. inlet_flow carries the command: the first
    flow at the start and each change at the last tick before it was applied.
    log_time = publish_time = the stamp (an offline run has no transport).
    Returns the number of ticks written; raises ParameterError for a bad interval.
    """
    record_interval = waveforms.time[1] - waveforms.time[0]
    every = round(publish_interval / record_interval)
    if every < 1 or abs(every * record_interval - publish_interval) > 1e-9 * publish_interval:
        raise ParameterError(f"publish interval {publish_interval:g} s is not a whole multiple of the "
                             f"waveforms' sample interval {record_interval:g} s")
    bag = BagWriter(path)
    tick = TickMessages()
    try:
        for topic, type_name in TOPIC_TYPES.items():
            bag.add_topic("/" + topic, type_name)
        indices = range(0, len(waveforms.time), every)
        commanded = None
        for previous, index in zip([None, *indices], indices):
            time_ns = start_time_ns + round(waveforms.time[index] * NS_PER_S)
            flow = float(waveforms.inlet_flow[index])
            if flow != commanded:
                command_ns = time_ns if previous is None else start_time_ns + round(waveforms.time[previous] * NS_PER_S)
                bag.write_message("/inlet_flow", Float64(data=flow), command_ns, command_ns)
                commanded = flow
            for topic, message in tick.fill(time_ns, waveforms.states[index], flow, ambient_pressure):
                bag.write_message("/" + topic, message, time_ns, time_ns)
        return len(indices)
    finally:
        bag.close()
