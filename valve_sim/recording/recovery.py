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
Damaged MCAP files: a complete copy of what they still hold.

repair() does what `mcap recover` does: it reads the file record by record
(mcap_scan.Scan: every schema, channel, message, metadata and attachment it can,
past damage), and writes them to a new, complete MCAP file: chunked, with message
indexes, chunk indexes, statistics and summary. One record is in memory at a time.
repair_folder() repairs a rosbag2 bag folder file by file and writes the new
folder's metadata.yaml, as `ros2 bag reindex` does.
"""

from dataclasses import dataclass
from pathlib import Path

from mcap.records import Attachment, Channel, Header, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer
from valve_sim.core.errors import InputFileError
from valve_sim.core.input_documents import parse_yaml
from valve_sim.core.input_files import BAG_RECORD
from valve_sim.core.output_files import replacing
from valve_sim.recording import rosbag2_metadata
from valve_sim.recording.mcap_scan import Scan


CHUNK_SIZE = 768 * 1024  # [bytes] chunks of the repaired file: rosbag2's default


@dataclass(frozen=True)
class RepairReport:
    """
    What repair() kept, and what was wrong with the source.

    topics: {topic: messages kept}; topic_metadata: [(topic, type, offered QoS
    profiles, type hash, messages)] as rosbag2_metadata.bag_metadata() takes them;
    start_ns, end_ns: the first and last receive time kept [ns]; custom_data: the
    source's rosbag2 custom data (None without).
    """

    source: Path
    target: Path
    topics: dict
    complete_chunks: int
    partial_chunk_messages: int
    damage: str
    topic_metadata: list
    start_ns: int
    end_ns: int
    custom_data: dict = None
    skipped: tuple = ()  # (start, end) byte ranges of the source passed over as corrupt

    @property
    def messages(self):
        return sum(self.topics.values())

    def summary(self):
        """Say what was wrong and what was kept, for the user."""
        topics = ', '.join(f'{topic} {count}' for topic, count in sorted(self.topics.items()))
        partial = (
            f' and {self.partial_chunk_messages} from the chunk cut short'
            if self.partial_chunk_messages
            else ''
        )
        passed = ', '.join(f'{start}-{end}' for start, end in self.skipped)
        resynchronised = f'; passed over corrupt bytes {passed}' if passed else ''
        return (
            f'{self.damage or f"{self.source} was complete"}{resynchronised}\n'
            f'kept {self.messages} messages ({topics or "no topics"}) from '
            f'{self.complete_chunks} complete chunk(s){partial}; wrote {self.target}'
        )


def repair(source, target, explicit=False):
    """
    Write everything source still holds into target as a complete MCAP file.

    The copy is written to a temporary file renamed to target when complete
    (output_files.replacing): explicit says the user named target (a link there is
    followed); else a link at target is replaced, never followed. Returns a
    RepairReport. Raises InputFileError for a file that is not MCAP or has no header,
    or when target is source (a repair never overwrites what it reads).
    """
    source, target = Path(source), Path(target)
    if target.exists() and target.resolve() == source.resolve():
        raise InputFileError(f'{target} is the file being repaired; write to another file')
    scan = Scan(source)
    records = scan.records()
    header = next(records, None)
    if not isinstance(header, Header):
        raise InputFileError(f'{scan.damage or source}: no MCAP header, nothing to recover')
    try:
        with replacing(target, 'wb', explicit) as stream:
            writer = Writer(stream, chunk_size=CHUNK_SIZE, compression=CompressionType.NONE)
            writer.start(profile=header.profile, library=header.library)
            copied = _Copy(writer)
            for record in records:
                copied.add(record)
            writer.finish()
    except OSError as error:
        raise InputFileError(f'cannot write {target}: {error.strerror}') from error
    return RepairReport(
        source,
        target,
        {topic: topic_metadata[4] for topic, topic_metadata in copied.topics.items()},
        scan.complete_chunks,
        scan.partial_chunk_messages,
        scan.damage,
        [tuple(topic_metadata) for topic_metadata in copied.topics.values()],
        *copied.log_times,
        copied.custom_data,
        tuple(scan.skipped),
    )


def repair_folder(source, target):
    """
    Repair every MCAP file of the bag folder source into the new folder target.

    Writes target/metadata.yaml for the repaired files, as `ros2 bag reindex` does.
    Returns the RepairReports, one per file in the bag's order. Each file is written
    whole or not at all (repair()); links inside target are replaced, not followed.
    """
    target = Path(target)
    files = rosbag2_metadata.bag_files(source)
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise InputFileError(f'cannot create {target}: {error.strerror}') from error
    reports = [repair(file, target / file.name) for file in files]
    metadata = rosbag2_metadata.bag_metadata(
        [(r.target.name, r.topic_metadata, r.start_ns, r.end_ns) for r in reports],
        custom_data=next((r.custom_data for r in reports if r.custom_data), None),
    )
    rosbag2_metadata.write_metadata_file(target, metadata)
    return reports


class _Copy:
    """
    Writes records to a Writer, each schema and channel once.

    Notes per topic [topic, type, offered QoS profiles, type hash, messages], the
    span of receive times and the rosbag2 custom data, for the bag's metadata.
    """

    def __init__(self, writer):
        self.writer = writer
        self.schemas = {0: (0, '')}  # source id -> (target id, type name)
        self.channels = {}  # source id -> (target id, topic)
        self.topics = {}
        self.log_times = [rosbag2_metadata.NOT_STARTED_NS, 0]
        self.custom_data = None

    def add(self, record):
        writer = self.writer
        if isinstance(record, Schema) and record.id not in self.schemas:
            self.schemas[record.id] = (
                writer.register_schema(record.name, record.encoding, record.data),
                record.name,
            )
        elif isinstance(record, Channel) and record.id not in self.channels:
            schema_id, type_name = self.schemas.get(record.schema_id, (0, ''))
            metadata = dict(record.metadata)
            self.channels[record.id] = (
                writer.register_channel(
                    record.topic, record.message_encoding, schema_id, metadata
                ),
                record.topic,
            )
            self.topics.setdefault(
                record.topic,
                [
                    record.topic,
                    type_name,
                    _profiles(metadata.get('offered_qos_profiles', '')),
                    metadata.get('topic_type_hash', ''),
                    0,
                ],
            )
        elif isinstance(record, Message) and record.channel_id in self.channels:
            channel_id, topic = self.channels[record.channel_id]
            writer.add_message(
                channel_id,
                log_time=record.log_time,
                data=record.data,
                publish_time=record.publish_time,
                sequence=record.sequence,
            )
            self.topics[topic][4] += 1
            self.log_times[0] = min(self.log_times[0], record.log_time)
            self.log_times[1] = max(self.log_times[1], record.log_time)
        elif isinstance(record, Metadata):
            writer.add_metadata(record.name, dict(record.metadata))
            if record.name == rosbag2_metadata.RECORD_NAME:
                self.custom_data = _custom_data(record.metadata) or self.custom_data
        elif isinstance(record, Attachment):
            writer.add_attachment(
                record.create_time, record.log_time, record.name, record.media_type, record.data
            )


def _profiles(text):
    """Return the offered QoS profiles of a channel's metadata (YAML), [] if none is readable."""
    try:
        profiles = parse_yaml(text, BAG_RECORD, 'offered_qos_profiles')
    except InputFileError:
        return []
    return profiles if isinstance(profiles, list) else []


def _custom_data(metadata):
    """custom_data of a rosbag2 Metadata record's serialized BagMetadata, or None."""
    try:
        bag = parse_yaml(
            metadata.get(rosbag2_metadata.RECORD_KEY, ''), BAG_RECORD, rosbag2_metadata.RECORD_KEY
        )
    except InputFileError:
        return None
    custom_data = bag.get('custom_data') if isinstance(bag, dict) else None
    return custom_data if isinstance(custom_data, dict) else None
