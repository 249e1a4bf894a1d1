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
Bags as rosbag2 (Jazzy) writes them: the 'rosbag2' metadata record, bag folders, reading either.

The expected metadata layout is spelled out here from rosbag2's Jazzy source
(rosbag2_storage/yaml.hpp, convert<BagMetadata>::encode and the converters it calls;
rosbag2_storage/bag_metadata.hpp, version 9; rosbag2_storage_mcap/mcap_storage.cpp,
update_metadata) and checked against what rosbags, an independent reader and
writer of rosbag2 bags, reads and writes.
"""


from pathlib import Path

from mcap.reader import make_reader
import pytest
from valve_sim.analysis.recorded_steps import analyse
from valve_sim.commands.cli import main
from valve_sim.core.errors import InputFileError
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import FlowStep, relief_flows, simulate
from valve_sim.recording.bag import BagWriter
from valve_sim.recording.rosbag2_metadata import bag_files
from valve_sim.recording.signal_reader import read_recording
from valve_sim.recording.valve_topics import (
    TOPIC_TYPES,
    TRANSPORT_DELAY_NS,
    TRANSPORT_JITTER_CAP_NS,
    write_simulation_bag,
)
import yaml


# An offline bag has no tank_pressure (the tank at ambient: nobody sent it) and no
# inlet_flow_stamped (lockstep's input; the flow comes on inlet_flow).
OFFLINE_UNSENT = ('tank_pressure', 'inlet_flow_stamped')
START_NS = 1_795_953_600 * 10**9  # 2026-11-29T12:00:00Z
# YAML::convert<...>::encode of rosbag2 Jazzy (yaml.hpp, qos.cpp), version 9, in order.
DURATION = {'nanoseconds': None}
TIME_POINT = {'nanoseconds_since_epoch': None}
RMW_TIME = {'sec': None, 'nsec': None}
QOS = {
    'history': None,
    'depth': None,
    'reliability': None,
    'durability': None,
    'deadline': RMW_TIME,
    'lifespan': RMW_TIME,
    'liveliness': None,
    'liveliness_lease_duration': RMW_TIME,
    'avoid_ros_namespace_conventions': None,
}
TOPIC_INFORMATION = {
    'topic_metadata': {
        'name': None,
        'type': None,
        'serialization_format': None,
        'offered_qos_profiles': [QOS],  # version >= 9: a YAML sequence, not a string
        'type_description_hash': None,
    },
    'message_count': None,
}
BAG_METADATA = {
    'version': None,
    'storage_identifier': None,
    'duration': DURATION,
    'starting_time': TIME_POINT,
    'message_count': None,
    'topics_with_message_count': [TOPIC_INFORMATION],
    'compression_format': None,
    'compression_mode': None,
    'relative_file_paths': [None],
    'files': [
        {'path': None, 'starting_time': TIME_POINT, 'duration': DURATION, 'message_count': None}
    ],
    'custom_data': {},  # a map (null when empty)
    'ros_distro': None,
}


def layout_problems(value, layout, ordered=True, where='metadata'):
    """Differences of value's keys (in yaml-cpp's order if ordered) from a layout."""
    if isinstance(layout, dict):
        if layout == {}:
            return [] if value is None or isinstance(value, dict) else [f'{where} is no map']
        keys = list(value) if isinstance(value, dict) else None
        if keys is None or (keys if ordered else sorted(keys)) != (
            list(layout) if ordered else sorted(layout)
        ):
            return [f'{where}: keys {keys}']
        return [
            problem
            for key in layout
            for problem in layout_problems(value[key], layout[key], ordered, f'{where}.{key}')
        ]
    if isinstance(layout, list):
        if not isinstance(value, list) or not value:
            return [f'{where} is no (non-empty) list']
        return [p for item in value for p in layout_problems(item, layout[0], ordered, where)]
    return [f'{where} is a collection'] if isinstance(value, (dict, list)) else []


@pytest.fixture(scope='module')
def waveforms():
    return simulate(load_parameters().params, FlowStep(step_time=0.1, end_time=0.4))


@pytest.fixture(scope='module')
def bag_folder(waveforms, tmp_path_factory):
    folder = tmp_path_factory.mktemp('bags') / 'step'
    relief = relief_flows(load_parameters().params, waveforms)
    write_simulation_bag(folder, waveforms, start_time_ns=START_NS, folder=True, relief=relief)
    return folder


def mcap_summary(path):
    """(statistics, {topic: channel}, [rosbag2 metadata records as dicts]) of an MCAP file."""
    with open(path, 'rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        records = [
            yaml.safe_load(record.metadata['serialized_metadata'])
            for record in reader.iter_metadata()
            if record.name == 'rosbag2'
        ]
        topics = {channel.topic: channel for channel in summary.channels.values()}
        return summary.statistics, topics, records


def test_bag_folder_has_rosbag2_jazzy_metadata(bag_folder):
    assert sorted(p.name for p in bag_folder.iterdir()) == ['metadata.yaml', 'step_0.mcap']
    document = yaml.safe_load((bag_folder / 'metadata.yaml').read_text())
    assert list(document) == ['rosbag2_bagfile_information']
    metadata = document['rosbag2_bagfile_information']
    assert layout_problems(metadata, BAG_METADATA) == []
    statistics, channels, records = mcap_summary(bag_folder / 'step_0.mcap')
    assert metadata['version'] == 9 and metadata['storage_identifier'] == 'mcap'
    assert metadata['ros_distro'] == 'jazzy'
    assert metadata['relative_file_paths'] == ['step_0.mcap']
    assert metadata['compression_format'] == metadata['compression_mode'] == ''
    assert metadata['message_count'] == statistics.message_count
    assert metadata['starting_time']['nanoseconds_since_epoch'] == statistics.message_start_time
    assert (
        metadata['duration']['nanoseconds']
        == statistics.message_end_time - statistics.message_start_time
    )
    assert metadata['files'] == [
        {
            'path': 'step_0.mcap',
            'starting_time': metadata['starting_time'],
            'duration': metadata['duration'],
            'message_count': statistics.message_count,
        }
    ]
    by_topic = {t['topic_metadata']['name']: t for t in metadata['topics_with_message_count']}
    assert list(by_topic) == ['/' + topic for topic in TOPIC_TYPES if topic not in OFFLINE_UNSENT]
    for name, topic in by_topic.items():
        channel = channels[name]
        assert topic['message_count'] == statistics.channel_message_counts[channel.id]
        assert topic['topic_metadata']['type'] == TOPIC_TYPES[name[1:]]
        assert topic['topic_metadata']['serialization_format'] == 'cdr'
        assert topic['topic_metadata']['type_description_hash'] == (
            channel.metadata['topic_type_hash']
        )
        assert topic['topic_metadata']['type_description_hash'].startswith('RIHS01_')
        assert topic['topic_metadata']['offered_qos_profiles'] == yaml.safe_load(
            channel.metadata['offered_qos_profiles']
        )
    # Inside the MCAP file: the record of the opening (no messages yet), then the final one.
    assert len(records) == 2 and records[1] == metadata
    assert records[0]['message_count'] == 0 and records[0]['topics_with_message_count'] == []
    assert records[0]['starting_time']['nanoseconds_since_epoch'] == 2**63 - 1


def test_rosbags_reads_the_bag_folder_and_its_metadata(bag_folder, waveforms):
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import Reader

    with Reader(bag_folder) as reader:
        assert reader.ros_distro == 'jazzy'
        custom_data = reader.storage.metadata.custom  # rosbags has no public accessor
        assert custom_data == {'source': 'valve-sim simulate (offline model run)'}
        assert {c.topic: c.msgcount for c in reader.connections} == {
            **{
                '/' + t: len(waveforms.time[::10])
                for t in TOPIC_TYPES if t not in ('inlet_flow', *OFFLINE_UNSENT)
            },
            '/inlet_flow': 2,
        }
        assert sum(1 for _ in reader.messages()) == reader.message_count
        qos = next(c for c in reader.connections if c.topic == '/supply_pressure')
        assert qos.ext.offered_qos_profiles[0].reliability.name == 'RELIABLE'
        assert qos.digest.startswith('RIHS01_')
    with AnyReader([bag_folder]) as reader:
        connection = next(c for c in reader.connections if c.topic == '/supply_pressure')
        first = next(reader.messages([connection]))
        message = reader.deserialize(first[2], connection.msgtype)
        assert message.header.frame_id == 'relief_valve/supply_port'
        assert message.fluid_pressure == pytest.approx(waveforms['supply_pressure'][0] + 101325.0)


def test_rosbags_own_rosbag2_writer_writes_the_same_metadata(bag_folder, tmp_path):
    """rosbags, writing version 9 for the same topics and QoS, agrees on layout and values."""
    from rosbags.rosbag2 import Reader, StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores

    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag_folder) as ours, Writer(
        tmp_path / 'other', version=9, storage_plugin=StoragePlugin.MCAP
    ) as writer:
        for connection in ours.connections:
            added = writer.add_connection(
                connection.topic,
                connection.msgtype,
                typestore=typestore,
                offered_qos_profiles=connection.ext.offered_qos_profiles,
            )
            for _, timestamp, data in ours.messages([connection]):
                writer.write(added, timestamp, data)
    theirs = yaml.safe_load((tmp_path / 'other' / 'metadata.yaml').read_text())
    theirs = theirs['rosbag2_bagfile_information']
    assert layout_problems(theirs, BAG_METADATA, ordered=False) == []  # rosbags sorts keys
    mine = yaml.safe_load((bag_folder / 'metadata.yaml').read_text())
    mine = mine['rosbag2_bagfile_information']
    same = ('version', 'storage_identifier', 'message_count', 'duration', 'starting_time')
    for key in same:
        assert mine[key] == theirs[key], key
    # Same topics, counts, QoS and type hashes (rosbags computes its hashes itself).
    assert mine['topics_with_message_count'] == theirs['topics_with_message_count']


def test_received_after_sent_at_a_realistic_epoch(bag_folder):
    from valve_sim.recording.bag import BagReader

    reader = BagReader(bag_files(bag_folder)[0])
    delays = [message.log_time - message.publish_time for _, _, message in reader.messages()]
    assert min(delays) >= TRANSPORT_DELAY_NS
    assert max(delays) <= TRANSPORT_DELAY_NS + TRANSPORT_JITTER_CAP_NS
    assert len(set(delays)) > len(delays) // 2  # jitter, not a constant offset


def test_analyse_takes_a_bag_folder_like_its_file(bag_folder, tmp_path, capsys):
    folder_steps = analyse(read_recording(bag_folder))
    file_steps = analyse(read_recording(bag_folder / 'step_0.mcap'))
    assert folder_steps == file_steps and len(folder_steps) == 1
    assert main(['analyse', str(bag_folder)]) == 0
    assert 'step 1: up' in capsys.readouterr().out
    unclosed = tmp_path / 'unclosed'  # a recording killed before it wrote metadata.yaml
    unclosed.mkdir()
    (unclosed / 'unclosed_0.mcap').write_bytes((bag_folder / 'step_0.mcap').read_bytes())
    assert bag_files(unclosed) == [unclosed / 'unclosed_0.mcap']
    assert analyse(read_recording(unclosed)) == folder_steps


def test_bag_folder_problems_are_clear_errors(bag_folder, tmp_path, capsys):
    missing = tmp_path / 'missing_file'
    missing.mkdir()
    (missing / 'metadata.yaml').write_text((bag_folder / 'metadata.yaml').read_text())
    sqlite = tmp_path / 'sqlite'
    sqlite.mkdir()
    (sqlite / 'metadata.yaml').write_text(
        'rosbag2_bagfile_information:\n  storage_identifier: sqlite3\n'
        '  relative_file_paths: [sqlite_0.db3]\n'
    )
    broken = tmp_path / 'broken'
    broken.mkdir()
    (broken / 'metadata.yaml').write_text('rosbag2_bagfile_information: [\n')
    empty = tmp_path / 'empty'
    empty.mkdir()
    cases = {
        missing: 'step_0.mcap named in metadata.yaml is missing',
        sqlite: "storage 'sqlite3'",
        broken: 'is not valid YAML',
        empty: 'neither metadata.yaml nor .mcap files',
    }
    for path, message in cases.items():
        with pytest.raises(InputFileError, match=message):
            bag_files(path)
        assert main(['analyse', str(path)]) == 1
        error = capsys.readouterr().err
        assert message in error and str(path) in error and error.count('\n') == 1, error
    with pytest.raises(InputFileError, match='already exists'):
        BagWriter(bag_folder, folder=True)


def test_simulate_writes_a_bag_folder(tmp_path, capsys):
    folder = tmp_path / 'run'
    start = ['--start-time', '2026-11-29T12:00:00Z']
    code = main(
        ['simulate', '--end-time', '0.3', '--step-time', '0.1', '--mcap', str(folder)]
        + ['--bag-folder', *start]
    )
    assert code == 0, capsys.readouterr().err
    metadata = yaml.safe_load((folder / 'metadata.yaml').read_text())
    start = metadata['rosbag2_bagfile_information']['starting_time']['nanoseconds_since_epoch']
    assert START_NS < start < START_NS + 10**6  # the first message, received after its delay
    assert main(['simulate', '--bag-folder']) == 1
    assert 'need --mcap' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(['simulate', '--mcap', str(folder), '--start-time', 'yesterday'])
    assert 'not an ISO 8601 time' in capsys.readouterr().err


def test_sample_bag_has_receive_times_and_rosbag2_metadata():
    from valve_sim.recording.bag import BagReader

    sample = Path(__file__).resolve().parents[2] / 'bags' / 'reference_step.mcap'
    first = next(BagReader(sample).messages())[2]
    assert first.publish_time == START_NS < first.log_time <= START_NS + 10**6
    statistics, _, records = mcap_summary(sample)
    assert records[-1]['ros_distro'] == 'jazzy'
    assert records[-1]['message_count'] == statistics.message_count
    assert layout_problems(records[-1], BAG_METADATA) == []


def test_bag_files_of_an_unclosed_split_bag_in_split_order(tmp_path):
    for number in (10, 2, 0, 1):
        (tmp_path / f'bag_{number}.mcap').write_bytes(b'')
    assert [f.name for f in bag_files(tmp_path)] == [
        'bag_0.mcap', 'bag_1.mcap', 'bag_2.mcap', 'bag_10.mcap'
    ]
    assert bag_files(tmp_path / 'bag_2.mcap') == [tmp_path / 'bag_2.mcap']


def test_calibrate_reads_a_bag_folder(tmp_path, capsys):
    """`calibrate --bag` takes a bag folder as analyse does (read_recording, bag_files)."""
    folder = tmp_path / 'flat'
    start = ('--start-time', '2026-11-29T12:00:00Z')
    flat = ('--final-flow', '5L/min', '--end-time', '0.3', '--mcap', folder, '--bag-folder')
    assert main(['simulate', *map(str, flat), *start]) == 0
    capsys.readouterr()
    code = main(['calibrate', '--bag', str(folder), '--fit', 'd_c', '--out', str(tmp_path / 'o')])
    assert code == 1 and 'no usable step' in capsys.readouterr().err  # read, then judged
