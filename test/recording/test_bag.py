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
MCAP files as rosbag2 writes them, and their offline analysis.

The files: valve_sim.recording.bag, valve_topics; the offline analysis: bag_analysis.
"""

import json
from pathlib import Path
import subprocess
import sys

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.writer import Writer
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import Float64
from valve_sim.analysis.recorded_steps import analyse
from valve_sim.analysis.steps.measures import MEASURE_NAMES, step_measures
from valve_sim.commands.cli import main
from valve_sim.core.errors import InputFileError
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import FlowStep, relief_flows, simulate
from valve_sim.recording.bag import (
    BagReader,
    BagWriter,
    DEFAULT_OFFER,
    message_adder,
    message_definition,
    qos_profiles_yaml,
    SEPARATOR,
)
from valve_sim.recording.recovery import repair
from valve_sim.recording.signal_reader import read_recording
from valve_sim.recording.valve_topics import TOPIC_TYPES, write_simulation_bag
import yaml


# An offline bag has no tank_pressure (the tank at ambient: nobody sent it) and no
# inlet_flow_stamped (lockstep's input; the flow comes on inlet_flow).
OFFLINE_UNSENT = ('tank_pressure', 'inlet_flow_stamped')


ROOT = Path(__file__).resolve().parents[2]
SAMPLE_BAG = ROOT / 'bags' / 'reference_step.mcap'
START_NS = 1_700_000_000 * 10**9


@pytest.fixture(scope='module')
def waveforms():
    """
    Simulate the paper's step, shortened to 0.6 s.

    The step is at 0.25 s; its window is then truncated.
    """
    return simulate(load_parameters().params, FlowStep(step_time=0.25, end_time=0.6))


@pytest.fixture(scope='module')
def simulation_bag(waveforms, tmp_path_factory):
    path = tmp_path_factory.mktemp('bags') / 'simulation.mcap'
    relief = relief_flows(load_parameters().params, waveforms)
    write_simulation_bag(path, waveforms, start_time_ns=START_NS, relief=relief)
    return path


def run_cli(capsys, *arguments):
    """valve-sim in this process: (exit code, stdout, stderr)."""
    code = main([str(argument) for argument in arguments])
    out, err = capsys.readouterr()
    return code, out, err


def test_definition_is_rosbag2_full_text():
    text = message_definition('diagnostic_msgs/msg/DiagnosticArray')
    share = Path(sys.prefix) / 'share'
    assert text.startswith((share / 'diagnostic_msgs/msg/DiagnosticArray.msg').read_text())
    nested = [line for line in text.splitlines() if line.startswith('MSG: ')]
    # Sorted per level, depth first, each type once (rosbag2's LocalMessageDefinitionSource).
    assert nested == [
        'MSG: diagnostic_msgs/DiagnosticStatus',
        'MSG: diagnostic_msgs/KeyValue',
        'MSG: std_msgs/Header',
        'MSG: builtin_interfaces/Time',
    ]
    assert text.count(f'\n{SEPARATOR}\nMSG: ') == 4
    key_value = (share / 'diagnostic_msgs/msg/KeyValue.msg').read_text()
    assert f'\n{SEPARATOR}\nMSG: diagnostic_msgs/KeyValue\n{key_value}' in text


def test_qos_profiles_are_rosbag2_yaml():
    text = qos_profiles_yaml([DEFAULT_OFFER])
    assert text.startswith(
        '- history: unknown\n  depth: 0\n  reliability: reliable\n  durability: volatile\n'
        '  deadline:\n    sec: 9223372036\n    nsec: 854775807\n'
    )
    assert text.endswith('  avoid_ros_namespace_conventions: false')
    assert (
        yaml.safe_load(qos_profiles_yaml([DEFAULT_OFFER, DEFAULT_OFFER]))[1]['liveliness']
        == 'automatic'
    )
    assert qos_profiles_yaml([]) == '[]'


def test_simulation_bag_has_valve_node_layout(simulation_bag, waveforms):
    with open(simulation_bag, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()} == {
            '/' + topic: type_name for topic, type_name in TOPIC_TYPES.items()
            if topic not in OFFLINE_UNSENT
        }
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            assert channel.message_encoding == 'cdr' and schema.encoding == 'ros2msg'
            assert schema.data.decode() == message_definition(schema.name)
            assert channel.metadata['offered_qos_profiles'] == qos_profiles_yaml([DEFAULT_OFFER])
            assert channel.metadata['topic_type_hash'].startswith('RIHS01_')
        ticks = len(range(0, len(waveforms.time), 10))
        counts = {
            summary.channels[i].topic: n
            for i, n in summary.statistics.channel_message_counts.items()
        }
        assert counts == {
            **{'/' + t: ticks for t in TOPIC_TYPES if t not in ('inlet_flow', *OFFLINE_UNSENT)},
            '/inlet_flow': 2,
        }
        decoded = {}
        for _, channel, message, ros in reader.iter_decoded_messages():
            decoded.setdefault(channel.topic, (message, ros))
    message, supply = decoded['/supply_pressure']
    assert supply.fluid_pressure == pytest.approx(waveforms['supply_pressure'][0] + 101325.0)
    assert (supply.header.stamp.sec, supply.header.stamp.nanosec) == (START_NS // 10**9, 0)
    assert message.publish_time == START_NS < message.log_time  # sent, then received
    assert list(decoded['/joint_states'][1].name) == ['main_valve', 'pilot_poppet']


def test_bag_decodes_with_rosbags(simulation_bag):
    from rosbags.highlevel import AnyReader

    with AnyReader([simulation_bag]) as reader:
        connections = [c for c in reader.connections if c.topic == '/applied_inlet_flow']
        flows = [
            reader.deserialize(raw, c.msgtype).velocity[0]
            for c, _, raw in reader.messages(connections)
        ]
        qos = next(
            c for c in reader.connections if c.topic == '/supply_pressure'
        ).ext.offered_qos_profiles
    assert flows[0] == pytest.approx(5 / 6e4) and flows[-1] == pytest.approx(20 / 6e4)
    assert qos[0].reliability.name == 'RELIABLE'


def test_offline_analysis_of_simulation_bag(simulation_bag, waveforms):
    records = analyse(read_recording(simulation_bag))
    assert len(records) == 1
    step = records[0]
    assert step['t_step'] == pytest.approx(START_NS / 1e9 + 0.25) and step['direction'] == 1
    assert 'truncated' in step['details']['note']
    # 0.35 s after the step p_s still swings: no final value, so no measure taken from it
    assert step['details']['final_value_settled'] is False
    for name in ('P_o_percent', 'P_1_percent', 'r_d', 'T_s_ms'):  # taken from p_inf, x_inf
        assert step[name] is None and 'has not settled' in step['reasons'][name], name
    offline = step_measures(waveforms.time, waveforms['supply_pressure'],
                            waveforms['main_valve_displacement'], 0.25, window=0.35)
    assert step['T_1_ms'] == pytest.approx(offline.values['T_1_ms'], abs=0.1)  # peaks: kept


def test_sample_bag_analyses_to_its_json():
    """The installed command itself, on the sample bag in bags/."""
    done = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'analyse', str(SAMPLE_BAG), '--json'],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    out = done.stdout
    expected = json.loads(SAMPLE_BAG.with_suffix('.measures.json').read_text())['steps']
    steps = json.loads(out)['steps']
    assert len(steps) == len(expected) == 1
    for name in MEASURE_NAMES:
        assert steps[0][name] == pytest.approx(expected[0][name], rel=1e-12)


def test_analyse_prints_table_and_plots(tmp_path, capsys):
    code, out, err = run_cli(capsys, 'analyse', SAMPLE_BAG, '--plot', tmp_path / 'figure.png')
    assert code == 0, err
    assert 'step 1: up at' in out and 'T_s_ms' in out and '(0.2500 s after the first' in out
    assert 'paper' not in out  # a bag does not say which valve it recorded: no paper column
    assert (tmp_path / 'figure.png').stat().st_size > 10_000


def write_rig_bag(path, waveforms, every=10):
    """
    Write the simulated run as a rig might record it.

    Other topic names, Float64 flow, no shared layout.
    """
    bag = BagWriter(path)
    bag.add_topic('/rig/p_supply', 'sensor_msgs/msg/FluidPressure')
    bag.add_topic('/rig/joints', 'sensor_msgs/msg/JointState')
    bag.add_topic('/rig/q_in', 'std_msgs/msg/Float64')
    for index in range(0, len(waveforms.time), every):
        time_ns = START_NS + round(waveforms.time[index] * 1e9)
        messages = {
            '/rig/p_supply': FluidPressure(
                fluid_pressure=float(waveforms['supply_pressure'][index])
            ),
            '/rig/joints': JointState(
                name=['spool'], position=[float(waveforms['main_valve_displacement'][index])]
            ),
            '/rig/q_in': Float64(data=float(waveforms.inlet_flow[index])),
        }
        for topic, message in messages.items():
            bag.write_message(topic, message, time_ns, time_ns)
    bag.close()


def test_topic_mapping_reads_a_rig_bag(waveforms, simulation_bag, tmp_path, capsys):
    rig = tmp_path / 'rig.mcap'
    write_rig_bag(rig, waveforms)
    mapping = [
        '--topic-supply-pressure',
        '/rig/p_supply',
        '--topic-main-valve',
        '/rig/joints',
        '--joint-main-valve',
        'spool',
        '--topic-inlet-flow',
        '/rig/q_in',
        '--ambient-pressure',
        '0',
    ]
    code, _, err = run_cli(capsys, 'analyse', rig, *mapping)
    assert code == 1 and 'has no header stamp' in err and 'receive clock' in err
    code, out, err = run_cli(capsys, 'analyse', rig, *mapping, '--clock', 'receive', '--json')
    assert code == 0, err
    rig_step = json.loads(out)['steps'][0]
    valve_step = analyse(read_recording(simulation_bag))[0]
    for name in MEASURE_NAMES:
        if valve_step[name] is None:
            assert (
                rig_step[name] is None and rig_step['reasons'][name] == valve_step['reasons'][name]
            )
        else:
            assert rig_step[name] == pytest.approx(valve_step[name], rel=1e-9)


def test_step_time_option_needs_no_flow(simulation_bag, waveforms, capsys):
    code, out, err = run_cli(
        capsys,
        'analyse',
        simulation_bag,
        '--step-time',
        START_NS / 1e9 + 0.25,
        '--topic-inlet-flow',
        '/absent',
        '--json',
    )
    assert code == 0, err
    step = json.loads(out)['steps'][0]
    offline = step_measures(waveforms.time, waveforms['supply_pressure'],
                            waveforms['main_valve_displacement'], 0.25, window=0.35)
    assert step['T_1_ms'] == pytest.approx(offline.values['T_1_ms'], abs=0.1)
    assert step['P_1_percent'] is None  # the truncated window has no settled final value


def chunked_bag(path, chunks=8, per_chunk=50):
    """Write a bag of supply-pressure messages in chunks of per_chunk messages each."""
    bag = BagWriter(path)
    bag.add_topic('/supply_pressure', 'sensor_msgs/msg/FluidPressure')
    for k in range(chunks * per_chunk):
        bag.write_message('/supply_pressure', {'fluid_pressure': float(k)}, k, k)
        if (k + 1) % per_chunk == 0:
            bag.flush()
    bag.close()


def test_truncated_file_yields_what_repair_keeps(tmp_path):
    """Its complete chunks and the records of the chunk cut short, in order, as repair."""
    path = tmp_path / 'cut.mcap'
    chunked_bag(path)
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * 0.6)])
    reader = BagReader(path)
    values = [message.log_time for _, _, message in reader.messages()]
    assert 0 < len(values) < 400 and values == list(range(len(values)))
    assert 'ends before its footer' in reader.problem
    assert repair(path, tmp_path / 'repaired.mcap').messages == len(values)


def test_truncated_recording_analyses_with_warning(simulation_bag, tmp_path, capsys):
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(simulation_bag.read_bytes()[:-2000])
    code, out, err = run_cli(capsys, 'analyse', cut)
    assert code == 0 and 'warning' in err and 'ends before its footer' in err and 'step 1' in out


def test_damaged_file_is_a_clear_error(tmp_path, capsys):
    path = tmp_path / 'damaged.mcap'
    chunked_bag(path, chunks=2)
    data = bytearray(path.read_bytes())
    data[len(data) // 4:len(data) // 4 + 16] = bytes(16)
    path.write_bytes(bytes(data))
    with pytest.raises(InputFileError, match='is damaged'):
        list(BagReader(path).messages())
    code, _, err = run_cli(capsys, 'analyse', path)
    assert code == 1 and 'is damaged' in err and 'Traceback' not in err


def test_foreign_files_are_clear_errors(tmp_path, capsys):
    text = tmp_path / 'notes.mcap'
    text.write_text('not a bag\n')
    empty = tmp_path / 'empty.mcap'
    empty.write_bytes(b'')
    json_mcap = tmp_path / 'json.mcap'
    with open(json_mcap, 'wb') as stream:
        writer = Writer(stream)
        writer.start(profile='', library='test')
        channel = writer.register_channel('/foo', 'json', 0)
        writer.add_message(channel, log_time=1, data=b'{}', publish_time=1)
        writer.finish()
    (tmp_path / 'no_bag').mkdir()
    cases = {
        text: 'is not an MCAP file',
        empty: 'is not an MCAP file (it is empty)',
        tmp_path / 'no_bag': 'is a folder with neither metadata.yaml nor .mcap files',
        tmp_path / 'missing.mcap': 'cannot read',
        json_mcap: 'has no topic /supply_pressure',
    }
    for path, message in cases.items():
        assert main(['analyse', str(path)]) == 1
        error = capsys.readouterr().err
        assert message in error and error.count('\n') == 1, error


def test_stream_reader_of_mcap_reads_a_cut_file(simulation_bag, tmp_path):
    """The mcap library itself also reads the complete records of a file without its end."""
    cut = tmp_path / 'cut.mcap'
    cut.write_bytes(simulation_bag.read_bytes()[:-2000])
    records = []
    with open(cut, 'rb') as stream:
        with pytest.raises(Exception):
            for record in StreamReader(stream).records:
                records.append(record)
    assert sum(type(r).__name__ == 'Message' for r in records) > 0


def test_a_bag_recorded_in_a_namespace_needs_no_topic_options(waveforms, tmp_path, capsys):
    """One valve under /rig1: analyse finds it, or --namespace names it; two need the option."""
    bag = tmp_path / 'rig1.mcap'
    write_simulation_bag(bag, waveforms, start_time_ns=START_NS, namespace='/rig1')
    code, named, err = run_cli(capsys, 'analyse', bag, '--namespace', 'rig1', '--json')
    assert code == 0, err
    code, found, err = run_cli(capsys, 'analyse', bag, '--json')
    assert code == 0 and 'under /rig1' in err
    assert json.loads(found)['steps'] == json.loads(named)['steps'] != []
    code, _, err = run_cli(capsys, 'analyse', bag, '--namespace', '/rig2')
    assert code == 1 and 'no topic /rig2/supply_pressure' in err
    two = tmp_path / 'two.mcap'
    writer = BagWriter(two)
    for namespace in ('/rig1', '/rig2'):
        for topic, type_name in TOPIC_TYPES.items():
            writer.add_topic(f'{namespace}/{topic}', type_name)
    writer.close()
    code, _, err = run_cli(capsys, 'analyse', two)
    assert code == 1 and '2 namespaces: /rig1, /rig2; choose one with --namespace' in err


def test_simulate_writes_and_reads_a_namespace(tmp_path, capsys):
    """--namespace /rig1: the bag's topics below it, and the file's /rig1 section applies."""
    params = tmp_path / 'rig1.yaml'
    params.write_text('/rig1/relief_valve:\n  ros__parameters:\n    preset_pressure: 6.5e6\n')
    bag = tmp_path / 'sim.mcap'
    code, out, err = run_cli(capsys, 'simulate', '--namespace', '/rig1', '--params', params,
                             '--end-time', '0.4', '--mcap', bag, '--json')
    assert code == 0, err
    assert json.loads(out)['details']['p_0'] == pytest.approx(6.5e6, rel=0.01)
    with open(bag, 'rb') as stream:
        topics = {c.topic for c in make_reader(stream).get_summary().channels.values()}
    assert '/rig1/supply_pressure' in topics and '/supply_pressure' not in topics
    code, _, err = run_cli(capsys, 'simulate', '--params', params, '--end-time', '0.4')
    assert code == 1 and "'/rig1/relief_valve' (" in err and 'do not apply to /relief_valve' in err


def test_simulate_writes_a_rig_bag_with_a_slower_flowmeter(tmp_path, capsys):
    """--flow-interval: the flow topic every 10 ms, the pressure every 1 ms, in time order."""
    bag = tmp_path / 'slow.mcap'
    code, _, err = run_cli(capsys, 'simulate', '--end-time', '0.3', '--mcap', bag,
                           '--rig-topics', '/rig/p,/rig/q', '--flow-interval', '0.01')
    assert code == 0, err
    times = {'/rig/p': [], '/rig/q': []}
    for channel, _, message in BagReader(bag).messages():
        times[channel.topic].append(message.log_time)
    assert len(times['/rig/p']) == 301 and len(times['/rig/q']) == 31
    assert set(np.diff(times['/rig/q'])) == {10_000_000}
    code, _, err = run_cli(capsys, 'simulate', '--end-time', '0.3', '--flow-interval', '0.01')
    assert code == 1 and '--flow-interval needs --mcap and --rig-topics' in err


def test_message_adder_writes_the_bytes_of_add_message(tmp_path):
    """The recorder's lean add: byte for byte mcap's add_message, chunks and indexes too."""
    files = []
    for lean in (False, True):
        rng = np.random.default_rng(7)
        times = START_NS + rng.integers(0, 10**9, 3000)  # out of order, in and across chunks
        path = tmp_path / f'lean_{lean}.mcap'
        with open(path, 'wb') as stream:
            writer = Writer(stream, chunk_size=4096)
            writer.start(profile='ros2', library='test')
            schema = writer.register_schema('std_msgs/msg/Float64', 'ros2msg', b'float64 data')
            channels = [writer.register_channel(f'/t{k}', 'cdr', schema) for k in range(3)]
            add = message_adder(writer) if lean else writer.add_message
            for k, time_ns in enumerate(times.tolist()):
                add(channels[k % 3] if k % 7 else channels[0], time_ns,
                    bytes(rng.integers(0, 256, 4 + k % 37, dtype=np.uint8)), time_ns + k)
            writer.finish()
        files.append(path.read_bytes())
    assert files[0] == files[1]
    with open(tmp_path / 'lean_True.mcap', 'rb') as stream:
        assert len(list(make_reader(stream).iter_messages())) == 3000
    with open(tmp_path / 'plain.mcap', 'wb') as stream:
        unchunked = Writer(stream, use_chunking=False)
        assert message_adder(unchunked) == unchunked.add_message  # not chunked: mcap's own
