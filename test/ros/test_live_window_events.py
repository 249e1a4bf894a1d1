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
analyser_node's measures end a step's window at a change of valve_node's settings.

Its fault_status, and its parameter changes on /parameter_events: live (the measures
publisher fed messages) and in `valve-sim analyse` of a bag holding them, alike.
"""

import json
from types import SimpleNamespace

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import pytest
from rclpy.serialization import serialize_message
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.analysis.steps.signals import SignalMap
from valve_sim.core.simulation import FlowStep, simulate
from valve_sim.ros.measures_publisher import StepMeasures


def fault_status(time, blockage):
    """Serialize a fault_status message holding a setting from time [s] on."""
    array = DiagnosticArray(status=[DiagnosticStatus(name='relief_valve: faults', values=[
        KeyValue(key='fault.damping_orifice_blockage', value=repr(blockage))])])
    array.header.stamp.sec, array.header.stamp.nanosec = divmod(round(time * 1e9), 10**9)
    return serialize_message(array)


def test_a_fault_status_change_ends_the_window_live(reference, tmp_path):
    published = []
    logger = SimpleNamespace(info=lambda text: None, error=lambda text: None)
    node = SimpleNamespace(
        create_publisher=lambda *args: SimpleNamespace(publish=published.append),
        get_logger=lambda: logger, get_name=lambda: 'valve_analyser')
    measures = StepMeasures(node, SignalMap(), 1e-6, 0.05, 'test', tmp_path / 'run.mcap')
    extractor = measures.extractor('/fault_status', 'diagnostic_msgs/msg/DiagnosticArray')
    assert measures.extractor('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray') is None
    recorded = SimpleNamespace(extractor=extractor,
                               type_name='diagnostic_msgs/msg/DiagnosticArray',
                               subscription=SimpleNamespace(msg_type=DiagnosticArray))
    measures.add(recorded, fault_status(0.0, 0.0), 0)  # the settings at the start: no event
    measures.add(recorded, fault_status(0.0, 0.0), 0)  # the same again: no event either
    measures.add(recorded, fault_status(0.5, 0.3), 0)  # a change from 0.5 s on
    run = simulate(reference, FlowStep(step_time=0.25, end_time=1.3), record_interval=1e-3)
    for row in zip(run.time, run['supply_pressure'], run['main_valve_displacement'],
                   run.inlet_flow):
        measures._measured(measures.analysis.add(*row))
    measures.finish()
    (step,) = json.loads((tmp_path / 'run.measures.json').read_text())['steps']
    assert step['details']['window_cut']['time'] == pytest.approx(0.499)
    assert 'the event fault.damping_orifice_blockage = 0.3 at 0.500000 s' in \
        step['details']['window_cut']['by']
    assert len(published) == 1 and step['T_1_ms'] is not None


@pytest.fixture(scope='module')
def plain(tmp_path_factory):
    """Return a bag of valve_node's topics: the paper's step (5 -> 20 L/min at 0.25 s), 1.3 s."""
    import subprocess
    import sys

    path = tmp_path_factory.mktemp('bags') / 'plain.mcap'
    subprocess.run([sys.executable, '-m', 'valve_sim.commands.cli', 'simulate', '--end-time',
                    '1.3', '--mcap', str(path)], check=True, capture_output=True, timeout=300)
    return path


def copy_with(bag, path, topic, type_name, messages):
    """Copy a bag to path, with a topic of type_name added: messages [(time [s], bytes)]."""
    from valve_sim.recording.bag import BagReader, BagWriter

    reader, writer = BagReader(bag), BagWriter(path)
    try:
        for channel, schema, message in reader.messages():
            if channel.topic not in writer.channels:
                writer.add_topic(channel.topic, schema.name)
            writer.write(writer.channels[channel.topic], message.data, message.log_time,
                         message.publish_time)
        added = writer.add_topic(topic, type_name)
        for time, data in messages:
            writer.write(added, data, round(time * 1e9), round(time * 1e9))
    finally:
        writer.close()


def test_a_fault_status_change_in_a_bag_ends_the_window_offline(plain, tmp_path):
    """valve-sim analyse reads fault_status beside the valve's topics: the same rule."""
    from valve_sim.analysis.recorded_steps import analyse
    from valve_sim.recording.signal_reader import read_recording

    faulted = tmp_path / 'faulted.mcap'
    start = read_recording(plain).time[0]  # [s] the first tick's stamp
    copy_with(plain, faulted, '/fault_status', 'diagnostic_msgs/msg/DiagnosticArray',
              [(start + time, fault_status(start + time, blockage))
               for time, blockage in ((0.0, 0.0), (0.5, 0.3))])
    (plain_step,) = analyse(read_recording(plain))
    (step,) = analyse(read_recording(faulted))
    assert 'window_cut' not in plain_step['details'] and plain_step['T_s_ms'] is not None
    assert step['details']['window_cut']['by'].startswith(
        'the event fault.damping_orifice_blockage = 0.3 at ')
    assert step['T_s_ms'] is None and step['T_1_ms'] == pytest.approx(plain_step['T_1_ms'])


def parameter_event(time, node, declared=(), changed=()):
    """Serialize a ParameterEvent of node at time [s]: (name, value) pairs declared, changed."""
    from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterValue

    def parameters(pairs):
        return [Parameter(name=name, value=ParameterValue(type=3, double_value=value))
                for name, value in pairs]

    event = ParameterEvent(node=node, new_parameters=parameters(declared),
                           changed_parameters=parameters(changed))
    event.stamp.sec, event.stamp.nanosec = divmod(round(time * 1e9), 10**9)
    return serialize_message(event)


def parameter_events(start):
    """
    valve_node's parameter events [(time [s], bytes)] from start [s] on.

    Only the last changes the model: the others set a value it had, a publish-only
    parameter, or a parameter of a node in another namespace.
    """
    return [
        (start, parameter_event(start, '/relief_valve', declared=[
            ('damping_orifice_diameter', 0.0008), ('publish_rate', 1000.0)])),
        (start + 0.4, parameter_event(start + 0.4, '/relief_valve',
                                      changed=[('damping_orifice_diameter', 0.0008)])),
        (start + 0.45, parameter_event(start + 0.45, '/relief_valve',
                                       changed=[('publish_rate', 500.0)])),
        (start + 0.5, parameter_event(start + 0.5, '/rig2/relief_valve',
                                      changed=[('damping_orifice_diameter', 0.0009)])),
        (start + 0.6, parameter_event(start + 0.6, '/relief_valve',
                                      changed=[('damping_orifice_diameter', 0.0009)])),
    ]


def test_a_parameter_change_ends_the_window_live_and_offline_alike(plain, tmp_path):
    """`ros2 param set /relief_valve d_c ...` ends it; a value it had, publish_rate do not."""
    from rcl_interfaces.msg import ParameterEvent
    from valve_sim.analysis.recorded_steps import analyse
    from valve_sim.recording.signal_reader import read_recording

    changed = tmp_path / 'changed.mcap'
    start = read_recording(plain).time[0]  # [s] the first tick's stamp
    copy_with(plain, changed, '/parameter_events', 'rcl_interfaces/msg/ParameterEvent',
              parameter_events(start))
    (plain_step,) = analyse(read_recording(plain))
    (offline,) = analyse(read_recording(changed))
    cut = offline['details']['window_cut']
    assert cut['time'] == pytest.approx(start + 0.599)
    assert cut['by'] == ('the parameter change on /relief_valve: damping_orifice_diameter = '
                         f'0.0009 at {start + 0.6:.6f} s')
    assert offline['T_s_ms'] is None and offline['T_1_ms'] == pytest.approx(plain_step['T_1_ms'])

    published = []  # live: the measures publisher fed the same rows and events
    logger = SimpleNamespace(info=lambda text: None, error=lambda text: None)
    node = SimpleNamespace(
        create_publisher=lambda *args: SimpleNamespace(publish=published.append),
        get_logger=lambda: logger, get_name=lambda: 'valve_analyser')
    measures = StepMeasures(node, SignalMap(), 1e-6, 0.05, 'test', tmp_path / 'live.mcap')
    recorded = SimpleNamespace(
        extractor=measures.extractor('/parameter_events', 'rcl_interfaces/msg/ParameterEvent'),
        type_name='rcl_interfaces/msg/ParameterEvent',
        subscription=SimpleNamespace(msg_type=ParameterEvent))
    for _, data in parameter_events(start):
        measures.add(recorded, data, 0)
    run = read_recording(plain)
    for row in zip(run.time, run.supply_pressure, run.main_valve, run.inlet_flow):
        measures._measured(measures.analysis.add(*row))
    measures.finish()
    (live,) = json.loads((tmp_path / 'live.measures.json').read_text())['steps']
    assert live['details']['window_cut'] == pytest.approx(cut)
    assert {name: live[name] for name in MEASURE_NAMES} == \
        pytest.approx({name: offline[name] for name in MEASURE_NAMES})


def test_a_namespaced_analyser_watches_its_own_valve_node():
    """In /rig1, /rig1/relief_valve's changes count, the root's not."""
    from valve_sim.analysis.steps.input_events import ParameterChanges
    from valve_sim.analysis.steps.signals import ROLES
    from rclpy.serialization import deserialize_message
    from rcl_interfaces.msg import ParameterEvent

    rig = SignalMap(topics={role.name: '/rig1/' + role.topic for role in ROLES})
    changes = ParameterChanges(rig.valve_namespace())
    for node in ('/relief_valve', '/rig1/relief_valve'):
        event = changes.update(deserialize_message(
            parameter_event(1.0, node, changed=[('main_valve_mass', 0.1)]), ParameterEvent))
    assert event == (1.0, 'the parameter change on /rig1/relief_valve: main_valve_mass = 0.1')
    assert list(changes.nodes) == ['/rig1/relief_valve']
