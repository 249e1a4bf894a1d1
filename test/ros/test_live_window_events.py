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

"""analyser_node's measures end a step's window at a change in valve_node's fault_status."""

import json
from types import SimpleNamespace

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import pytest
from rclpy.serialization import serialize_message
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


def test_a_fault_status_change_in_a_bag_ends_the_window_offline(tmp_path):
    """valve-sim analyse reads fault_status beside the valve's topics: the same rule."""
    import subprocess
    import sys

    from valve_sim.analysis.recorded_steps import analyse
    from valve_sim.recording.bag import BagReader, BagWriter
    from valve_sim.recording.signal_reader import read_recording

    plain, faulted = tmp_path / 'plain.mcap', tmp_path / 'faulted.mcap'
    subprocess.run([sys.executable, '-m', 'valve_sim.commands.cli', 'simulate', '--end-time',
                    '1.3', '--mcap', str(plain)], check=True, capture_output=True, timeout=300)
    reader, writer = BagReader(plain), BagWriter(faulted)
    try:
        for channel, schema, message in reader.messages():
            if channel.topic not in writer.channels:
                writer.add_topic(channel.topic, schema.name)
            writer.write(writer.channels[channel.topic], message.data, message.log_time,
                         message.publish_time)
        status = writer.add_topic('/fault_status', 'diagnostic_msgs/msg/DiagnosticArray')
        start = round(read_recording(plain).time[0] * 1e9)  # [ns] the first tick's stamp
        for time, blockage in ((0.0, 0.0), (0.5, 0.3)):
            stamp = start + round(time * 1e9)
            writer.write(status, fault_status(stamp / 1e9, blockage), stamp, stamp)
    finally:
        writer.close()
    (plain_step,) = analyse(read_recording(plain))
    (step,) = analyse(read_recording(faulted))
    assert 'window_cut' not in plain_step['details'] and plain_step['T_s_ms'] is not None
    assert step['details']['window_cut']['by'].startswith(
        'the event fault.damping_orifice_blockage = 0.3 at ')
    assert step['T_s_ms'] is None and step['T_1_ms'] == pytest.approx(plain_step['T_1_ms'])
