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
rosbag2's bag metadata (Jazzy, version 9), and bag folders: where a bag's MCAP files are.

rosbag2 describes a bag with a BagMetadata (rosbag2_storage/bag_metadata.hpp), written
by YAML::convert<BagMetadata>::encode (rosbag2_storage/yaml.hpp) twice: inside every MCAP
file as the Metadata record 'rosbag2' (key 'serialized_metadata': the YAML text,
mcap_storage.cpp update_metadata), and, for a bag folder, as metadata.yaml (key
'rosbag2_bagfile_information', metadata_io.cpp). A bag folder NAME holds NAME_0.mcap
(NAME_1.mcap ... after a split) and metadata.yaml. Times are the messages' receive
times (log_time) in ns; durations from the first to the last of them.
"""

import os
from pathlib import Path
import re

from valve_sim.core.errors import InputFileError
from valve_sim.core.input_documents import read_yaml
from valve_sim.core.input_files import BAG_METADATA, shown
from valve_sim.core.output_files import write_text
import yaml


VERSION = 9  # rosbag2_storage::BagMetadata::version in Jazzy
STORAGE_IDENTIFIER = 'mcap'
METADATA_FILE = 'metadata.yaml'  # rosbag2_storage::MetadataIo::metadata_filename
TOP_KEY = 'rosbag2_bagfile_information'
RECORD_NAME = 'rosbag2'  # the MCAP Metadata record
RECORD_KEY = 'serialized_metadata'
# The distribution whose message definitions and type hashes valve_sim writes (its
# ros-jazzy wheels, package.xml); a ROS install's ROS_DISTRO wins, as in rosbag2.
DEFAULT_ROS_DISTRO = 'jazzy'
NOT_STARTED_NS = 2**63 - 1  # rosbag2's starting_time before the first message
SPLIT_NUMBER = re.compile(r'_(\d+)\.mcap$')


def ros_distro():
    """ROS_DISTRO of the environment, else the distribution valve_sim's messages come from."""
    return os.environ.get('ROS_DISTRO') or DEFAULT_ROS_DISTRO


def qos_profiles(offers):
    """
    rclcpp::QoS list as rosbag2 version 9 encodes it (rosbag2_storage/qos.cpp).

    offers: dicts like bag.DEFAULT_OFFER (policies as rmw's lower-case names,
    durations in ns).
    """

    def duration(ns):
        return {'sec': ns // 1_000_000_000, 'nsec': ns % 1_000_000_000}

    return [
        {
            'history': offer['history'],
            'depth': offer['depth'],
            'reliability': offer['reliability'],
            'durability': offer['durability'],
            'deadline': duration(offer['deadline_ns']),
            'lifespan': duration(offer['lifespan_ns']),
            'liveliness': offer['liveliness'],
            'liveliness_lease_duration': duration(offer['liveliness_lease_duration_ns']),
            'avoid_ros_namespace_conventions': offer['avoid_ros_namespace_conventions'],
        }
        for offer in offers
    ]


def bag_metadata(files, custom_data=None):
    """
    Return the BagMetadata of a bag, as YAML::convert<BagMetadata>::encode orders it.

    files: [(file name, topics, start_ns, end_ns)] in the bag's order; topics: [(name,
    type, QoS profiles as qos_profiles() encodes them, type hash, message count)];
    start_ns, end_ns: the file's first and last receive time [ns] (start NOT_STARTED_NS
    while there is none). A topic in several files is listed once, with its total.
    """
    topics, entries, spans = {}, [], []
    for file_name, file_topics, start_ns, end_ns in files:
        for name, type_name, profiles, type_hash, messages in file_topics:
            topics.setdefault(name, [type_name, profiles, type_hash, 0])[3] += messages
        count = sum(topic[4] for topic in file_topics)
        entries.append({'path': file_name, **_span(count, start_ns, end_ns)})
        if count:
            spans.append((start_ns, end_ns))
    count = sum(topic[3] for topic in topics.values())
    span = _span(
        count, min((s for s, _ in spans), default=0), max((e for _, e in spans), default=0)
    )
    return {
        'version': VERSION,
        'storage_identifier': STORAGE_IDENTIFIER,
        'duration': span['duration'],
        'starting_time': span['starting_time'],
        'message_count': count,
        'topics_with_message_count': [
            {
                'topic_metadata': {
                    'name': name,
                    'type': type_name,
                    'serialization_format': 'cdr',
                    'offered_qos_profiles': profiles,
                    'type_description_hash': type_hash,
                },
                'message_count': messages,
            }
            for name, (type_name, profiles, type_hash, messages) in topics.items()
        ],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [entry['path'] for entry in entries],
        'files': entries,
        'custom_data': dict(custom_data) if custom_data else None,
        'ros_distro': ros_distro(),
    }


def _span(count, start_ns, end_ns):
    """starting_time, duration and message_count of count messages received start_ns..end_ns."""
    return {
        'starting_time': {'nanoseconds_since_epoch': start_ns if count else NOT_STARTED_NS},
        'duration': {'nanoseconds': max(end_ns - start_ns, 0) if count else 0},
        'message_count': count,
    }


class _Dumper(yaml.SafeDumper):
    """YAML as yaml-cpp's emitter writes it: sequences indented under their key, '' as ""."""

    def increase_indent(self, flow=False, indentless=False):
        return super().increase_indent(flow, False)

    def ignore_aliases(self, data):
        return True  # starting_time and duration appear twice: written out both times


_Dumper.add_representer(
    str,
    lambda dumper, text: dumper.represent_scalar(
        'tag:yaml.org,2002:str', text, style='"' if not text else None
    ),
)
_Dumper.add_representer(
    type(None), lambda dumper, _: dumper.represent_scalar('tag:yaml.org,2002:null', '~')
)


def dump(data):
    """YAML text of rosbag2 metadata (block style, keys in the given order, no final newline)."""
    return yaml.dump(data, Dumper=_Dumper, sort_keys=False, default_flow_style=False).rstrip('\n')


def write_metadata_file(folder, metadata):
    """Write folder/metadata.yaml as rosbag2_storage::MetadataIo::write_metadata does (whole)."""
    write_text(Path(folder) / METADATA_FILE, dump({TOP_KEY: metadata}) + '\n')


def read_metadata_file(folder):
    """
    Return the BagMetadata dict of folder/metadata.yaml, read once and checked.

    InputFileError if it cannot be read (input_files.BAG_METADATA's limits), is not
    rosbag2 bag metadata of an MCAP bag, or names its files other than as plain strings.
    """
    path = Path(folder) / METADATA_FILE
    document = read_yaml(path, BAG_METADATA)
    metadata = document.get(TOP_KEY) if isinstance(document, dict) else None
    if not isinstance(metadata, dict):
        raise InputFileError(f'{path} is not rosbag2 bag metadata: it has no mapping {TOP_KEY}')
    storage, paths = metadata.get('storage_identifier'), metadata.get('relative_file_paths')
    if storage != STORAGE_IDENTIFIER:
        raise InputFileError(
            f'{path}: a bag of storage {shown(storage)} ({TOP_KEY}.storage_identifier); '
            f'valve_sim reads {STORAGE_IDENTIFIER} bags'
        )
    if not isinstance(paths, list) or not paths or not all(isinstance(p, str) for p in paths):
        raise InputFileError(
            f'{path} is not rosbag2 bag metadata: {TOP_KEY}.relative_file_paths must list '
            f'the file names of the bag, got {shown(paths)}'
        )
    return metadata


def bag_files(path):
    """
    Return the MCAP file(s) of a bag given as a file or as a rosbag2 bag folder.

    A file is itself. A folder with metadata.yaml: its relative_file_paths, in order,
    each of which must exist. A folder without one (a recording that never closed):
    its .mcap files by split number. Raises InputFileError naming what is missing.
    """
    path = Path(path)
    if not path.is_dir():
        return [path]  # BagReader says if it is missing or not MCAP
    if (path / METADATA_FILE).exists():
        names = read_metadata_file(path)['relative_file_paths']
        files = [path / Path(name).name for name in names]
        missing = [file.name for file in files if not file.is_file()]
        if missing:
            raise InputFileError(
                f'bag folder {path}: {", ".join(missing)} named in {METADATA_FILE} is missing'
            )
        return files

    def split_number(file):
        found = SPLIT_NUMBER.search(file.name)
        return (int(found.group(1)) if found else -1, file.name)

    files = sorted(path.glob('*.mcap'), key=split_number)
    if not files:
        raise InputFileError(f'{path} is a folder with neither {METADATA_FILE} nor .mcap files')
    return files
