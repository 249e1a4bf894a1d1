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
MCAP files as rosbag2 (ROS 2 Jazzy, storage plugin mcap) writes them, and reading them back.

Writing (BagWriter) follows what rosbag2 (storage plugin mcap) writes on Jazzy:
header profile "ros2"; one schema per type, named "pkg/msg/Type", encoding
"ros2msg", holding the full definition text (message_definition()); channels with
message encoding "cdr" and the metadata "offered_qos_profiles" (qos_profiles_yaml())
and "topic_type_hash"; messages as serialized CDR with log_time = receive time and
publish_time = send time [ns]; chunked, uncompressed (rosbag2's default), with
message indexes, chunk indexes and a Statistics record; the Metadata record 'rosbag2'
(rosbag2_metadata: the bag's metadata, version 9) when the file opens and again,
complete, when it closes. Every flush() completes the open chunk and hands it to the
operating system, so after a hard kill every flushed chunk can still be read.
BagWriter(folder=True) writes a rosbag2 bag folder: NAME/NAME_0.mcap and, on
close, NAME/metadata.yaml.

Reading (BagReader) goes through the file record by record, so a file whose end
is missing (a recording killed before it was closed) still yields every message of
its complete chunks; BagReader.problem then says what was missing. A file that is
not MCAP, or whose records are damaged, raises InputFileError.
"""

import json
import os
from pathlib import Path
import re
import struct
import sys

from mcap.opcode import Opcode
from mcap.records import Channel, Message, MessageIndex, Schema
from mcap.writer import CompressionType, Writer
from valve_sim.core.errors import InputFileError, OutputFileError
from valve_sim.core.output_files import create_new, named_file
from valve_sim.recording import rosbag2_metadata
from valve_sim.recording.mcap_scan import INDEX_FIXED, MESSAGE_FIXED, Scan
import yaml


LIBRARY = 'valve_sim (mcap-python writer, rosbag2 storage layout)'
CHUNK_SIZE = 768 * 1024  # [bytes] rosbag2's (libmcap's) default chunk size
SEPARATOR = '=' * 80
PRIMITIVE_TYPES = frozenset(
    (
        'bool',
        'byte',
        'char',
        'float32',
        'float64',
        'int8',
        'uint8',
        'int16',
        'uint16',
        'int32',
        'uint32',
        'int64',
        'uint64',
        'string',
        'wstring',
    )
)
# A field's type at the start of a line, as rosbag2 finds nested types in .msg text.
FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
INFINITE_NS = 9223372036854775807  # RMW_DURATION_INFINITE [ns]

# What DDS discovery reports for a publisher with the default reliable, volatile QoS
# (history and depth are not part of a DDS offer): what valve_node offers.
DEFAULT_OFFER = {
    'history': 'unknown',
    'depth': 0,
    'reliability': 'reliable',
    'durability': 'volatile',
    'deadline_ns': INFINITE_NS,
    'lifespan_ns': INFINITE_NS,
    'liveliness': 'automatic',
    'liveliness_lease_duration_ns': INFINITE_NS,
    'avoid_ros_namespace_conventions': False,
}


class PackedMessageIndex(MessageIndex):
    """A MessageIndex record written in one write (mcap's: two writes an entry)."""

    def write(self, stream):
        entries = [value for entry in self.records for value in entry]
        stream.write(struct.pack(f'{INDEX_FIXED.format}{len(entries)}Q', Opcode.MESSAGE_INDEX,
                                 6 + 8 * len(entries), self.channel_id, 8 * len(entries),
                                 *entries))


def message_adder(writer):
    """
    Return add(channel_id, log_time, data, publish_time): writer.add_message's work, leaner.

    mcap's Writer (chunked) writes a Message record field by field, a message index entry
    likewise; a recording on /clock has ~9 messages a tick. This does the same work on the
    Writer's own objects, each record in one write: the same file (test_bag compares).
    Where the Writer is not laid out as mcap 1.6 has it: writer.add_message itself.
    """
    try:
        statistics = writer._Writer__statistics
        chunk = writer._Writer__chunk_builder
        maybe_complete = writer._Writer__maybe_finalize_chunk
        indices, counts = chunk.message_indices, statistics.channel_message_counts
        chunk.record_writer._buffer.write, chunk.num_messages, chunk.message_start_time  # used
    except AttributeError:
        return writer.add_message
    pack, message_opcode = MESSAGE_FIXED.pack, int(Opcode.MESSAGE)

    def add(channel_id, log_time, data, publish_time):
        if statistics.message_count == 0 or log_time < statistics.message_start_time:
            statistics.message_start_time = log_time
        if log_time > statistics.message_end_time:
            statistics.message_end_time = log_time
        counts[channel_id] += 1
        statistics.message_count += 1
        if chunk.num_messages == 0 or log_time < chunk.message_start_time:
            chunk.message_start_time = log_time
        if log_time > chunk.message_end_time:
            chunk.message_end_time = log_time
        index = indices.get(channel_id)
        if not index:
            index = indices[channel_id] = PackedMessageIndex(channel_id=channel_id, records=[])
        buffer = chunk.record_writer._buffer  # a new one for each chunk
        index.records.append((log_time, buffer.tell()))
        chunk.num_messages += 1
        buffer.write(pack(message_opcode, 22 + len(data), channel_id, 0, log_time, publish_time))
        buffer.write(data)
        maybe_complete()

    return add


def _split_type(type_name):
    """('pkg', 'Type') of 'pkg/msg/Type' or 'pkg/Type'."""
    parts = type_name.split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise InputFileError(f"'{type_name}' is not a message type name (pkg/msg/Type)")


def interface_file(type_name, extension):
    """
    Path of the installed interface file (.msg or .json) of a message type.

    Looks in share/<pkg>/msg/ under every AMENT_PREFIX_PATH entry (a ROS install)
    and under this interpreter's prefix (the PyPI wheels).
    """
    package, name = _split_type(type_name)
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p] + [
        sys.prefix
    ]
    for prefix in prefixes:
        path = Path(prefix) / 'share' / package / 'msg' / f'{name}{extension}'
        if path.is_file():
            return path
    raise InputFileError(f'no {extension} file for {type_name} under {", ".join(prefixes)}')


def message_definition(type_name):
    """
    Full ros2msg definition of a message type, exactly as rosbag2 stores it in a schema.

    The type's .msg text, then for each nested type (sorted, depth first, each once):
    a newline, a line of 80 '=', a line 'MSG: <type as the .msg names it>' and its text.
    """
    seen = set()

    def text_with_dependencies(name):
        package = _split_type(name)[0]
        text = interface_file(name, '.msg').read_text()
        dependencies = sorted(
            {
                found if '/' in found else f'{package}/{found}'
                for found in FIELD_TYPE.findall(text)
                if found not in PRIMITIVE_TYPES
            }
        )
        for dependency in dependencies:
            if dependency not in seen:
                seen.add(dependency)
                text += f'\n{SEPARATOR}\nMSG: {dependency}\n' + text_with_dependencies(dependency)
        return text

    return text_with_dependencies(type_name)


def type_hash(type_name):
    """REP-2011 type hash 'RIHS01_...' of an installed message type, '' if unknown."""
    try:
        hashes = json.loads(interface_file(type_name, '.json').read_text())['type_hashes']
    except (InputFileError, KeyError, ValueError):
        return ''
    package, name = _split_type(type_name)
    return next(
        (h['hash_string'] for h in hashes if h['type_name'] == f'{package}/msg/{name}'), ''
    )


def qos_profiles_yaml(offers):
    """
    Channel metadata 'offered_qos_profiles' as rosbag2 Jazzy (metadata version 9) writes it.

    offers: dicts like DEFAULT_OFFER (policies as rmw's lower-case names, durations
    in ns). Returns YAML::Dump's text: a block list, no trailing newline ('[]' if empty).
    """
    profiles = rosbag2_metadata.qos_profiles(offers)
    if not profiles:
        return '[]'
    return yaml.safe_dump(profiles, sort_keys=False, default_flow_style=False).rstrip('\n')


class BagWriter:
    """
    Writes one rosbag2-style MCAP file, or a rosbag2 bag folder holding one.

    add_topic() once per topic, then write() serialized messages. path is the file,
    or with folder=True the bag folder (it must not exist yet, as for rosbag2);
    self.path is then the MCAP file in it. custom_data: {str: str} for the metadata.
    new=True: path is a name the writer chose, not the user: nothing may be there yet,
    not even a symbolic link (never followed).
    """

    def __init__(self, path, chunk_size=CHUNK_SIZE, folder=False, custom_data=None, new=False):
        self.folder = Path(path) if folder else None
        self.path = self.folder / f'{self.folder.name}_0.mcap' if folder else Path(path)
        try:
            if folder:
                self.folder.mkdir(parents=True, exist_ok=False)
            self._file = create_new(self.path) if new or folder else named_file(self.path)
        except FileExistsError as error:
            raise InputFileError(
                f'{self.folder or self.path} already exists; rosbag2 does not overwrite a bag'
            ) from error
        except OutputFileError:  # named_file's own words: a FIFO with no reader, a socket
            raise
        except OSError as error:
            raise InputFileError(f'cannot write {self.path}: {error.strerror}') from error
        self._mcap = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.NONE)
        self._mcap.start(profile='ros2', library=LIBRARY)
        self._add_message = message_adder(self._mcap)
        self._schemas = {}
        self._encoders = {}  # type name -> CDR encoder (write_message)
        self._channel_types = {}  # channel id -> type name
        self._topics = {}  # channel id -> [topic, type, offers, type hash, message count]
        self._custom_data = custom_data
        self._log_times = [rosbag2_metadata.NOT_STARTED_NS, 0]  # first, last [ns]
        self.channels = {}  # topic -> channel id
        self.message_count = 0
        self.bytes_written = 0  # [bytes] message payloads
        self._write_metadata()  # as rosbag2 does on opening: distro, file, no messages yet

    def add_topic(self, topic, type_name, offers=(DEFAULT_OFFER,)):
        """
        Register a topic of type 'pkg/msg/Type' with its publishers' offered QoS.

        Returns its channel id.
        """
        if type_name not in self._schemas:
            self._schemas[type_name] = self._mcap.register_schema(
                type_name, 'ros2msg', message_definition(type_name).encode()
            )
        metadata = {
            'offered_qos_profiles': qos_profiles_yaml(offers),
            'topic_type_hash': type_hash(type_name),
        }
        channel_id = self._mcap.register_channel(topic, 'cdr', self._schemas[type_name], metadata)
        self.channels[topic] = channel_id
        self._channel_types[channel_id] = type_name
        self._topics[channel_id] = [topic, type_name, list(offers), type_hash(type_name), 0]
        return channel_id

    def write(self, channel_id, data, log_time, publish_time):
        """Add one serialized (CDR) message; times in ns (receive time, send time)."""
        self._add_message(channel_id, log_time, data, publish_time)
        self._topics[channel_id][4] += 1
        times = self._log_times
        if log_time < times[0]:
            times[0] = log_time
        if log_time > times[1]:
            times[1] = log_time
        self.message_count += 1
        self.bytes_written += len(data)

    def metadata(self):
        """Return the rosbag2 BagMetadata (a dict) of what was written so far."""
        topics = [
            (name, type_name, rosbag2_metadata.qos_profiles(offers), type_hash, messages)
            for name, type_name, offers, type_hash, messages in self._topics.values()
        ]
        return rosbag2_metadata.bag_metadata(
            [(self.path.name, topics, *self._log_times)], custom_data=self._custom_data
        )

    def _write_metadata(self):
        """Add the Metadata record 'rosbag2' as rosbag2's mcap_storage update_metadata does."""
        self._mcap.add_metadata(
            rosbag2_metadata.RECORD_NAME,
            {rosbag2_metadata.RECORD_KEY: rosbag2_metadata.dump(self.metadata())},
        )

    def write_message(self, topic, message, log_time, publish_time):
        """
        Serialize a message for a topic's type and add it.

        message: an rclpy message or a dict of its fields. The CDR encoder is
        mcap_ros2's, built from the schema's definition text: it writes the bytes DDS
        sends (rclpy.serialization pads some types, e.g. JointState, with 4 stray
        bytes that strict readers such as rosbags refuse).
        """
        channel_id = self.channels[topic]
        type_name = self._channel_types[channel_id]
        if type_name not in self._encoders:
            from mcap_ros2._dynamic import serialize_dynamic

            self._encoders[type_name] = serialize_dynamic(
                type_name, message_definition(type_name)
            )[type_name]
        self.write(channel_id, self._encoders[type_name](message), log_time, publish_time)

    def flush(self):
        """Complete the open chunk and hand everything written so far to the operating system."""
        self._mcap.flush()

    def abandon(self):
        """Close the file as it is after a write error: what was written stays, no summary."""
        try:
            self._file.close()
        except OSError:
            pass  # the buffered rest could not be written either; the file is closed anyway

    def close(self):
        """
        Write the final rosbag2 metadata, the summary and the footer; close the file.

        The summary holds the schemas, channels, statistics and indexes. A bag
        folder gets its metadata.yaml.
        """
        if not self._file.closed:
            self._write_metadata()
            self._mcap.finish()
            self._file.close()
            if self.folder:
                rosbag2_metadata.write_metadata_file(self.folder, self.metadata())


class BagReader:
    """
    Messages of an MCAP file in file order, tolerant of a missing end.

    Iterate messages() for (channel, schema, message) of mcap.records. After the
    iteration, problem is None for a complete file, or says what was missing. The
    records come from mcap_scan.Scan, the reader `valve-sim repair` uses, so both give
    one verdict on a damaged file, as fast (a sparse hole is skipped, not read).
    """

    def __init__(self, path):
        self.path = Path(path)
        self.problem = None
        self.channels = {}  # id -> Channel
        self.schemas = {}  # id -> Schema
        if self.path.is_dir():
            raise InputFileError(
                f'{self.path} is a directory; rosbag2_metadata.bag_files() gives its .mcap files'
            )
        Scan(self.path)._file.close()  # a regular MCAP file, or InputFileError now

    def messages(self, topics=None):
        """Yield (channel, schema, message) for every message (of the given topics, if any)."""
        scan, undefined = Scan(self.path), None
        for record in scan.records():
            if isinstance(record, Message):
                channel = self.channels.get(record.channel_id)
                if channel is None:
                    undefined = undefined or record.channel_id
                elif topics is None or channel.topic in topics:
                    yield channel, self.schemas.get(channel.schema_id), record
            elif isinstance(record, Channel):
                self.channels[record.id] = record
            elif isinstance(record, Schema):
                self.schemas[record.id] = record
        repair = f'`valve-sim repair {self.path}` writes a complete copy of what it holds'
        if scan.damage and scan.truncated:
            self.problem = (
                f'{scan.damage}: it ends before its footer (a recording that was not closed); '
                f'read what its complete chunks hold; {repair}'
            )
        elif scan.damage:
            raise InputFileError(f'{scan.damage} (the file is damaged there); {repair}')
        elif undefined is not None:
            raise InputFileError(
                f'{self.path}: a message refers to channel {undefined}, never defined '
                f'(the file is damaged); {repair}'
            )
