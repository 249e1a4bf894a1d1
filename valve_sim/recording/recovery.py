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
Damaged MCAP files: where they are damaged, and a complete copy of what they hold.

A recording killed mid-write (kill -9, a full disk, a power cut) ends inside a
record and has no summary, so seeking readers (rosbags, the mcap library's
indexed reader, rosbag2) refuse it. diagnose() says where a file is truncated or
corrupt. repair() does what `mcap recover` does: it reads the file record by
record, keeps every schema, channel, message, metadata and attachment it can
(the records of a chunk cut short too, if the chunk is uncompressed, as
rosbag2's and ours are), and writes them to a new, complete MCAP file: chunked,
with message indexes, chunk indexes, statistics and summary. One record is in
memory at a time. repair_folder() repairs a rosbag2 bag folder file by file and
writes the new folder's metadata.yaml, as `ros2 bag reindex` does.
"""

from dataclasses import dataclass
from io import BytesIO
import os
from pathlib import Path
import struct
import zlib

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    ChunkIndex,
    Header,
    Message,
    Metadata,
    Schema,
)
from mcap.stream_reader import get_chunk_data_stream
from mcap.writer import CompressionType, Writer
from valve_sim.core.errors import InputFileError
from valve_sim.core.input_documents import parse_yaml
from valve_sim.core.input_files import BAG_RECORD, MCAP_FILE, open_regular
from valve_sim.core.output_files import replacing
from valve_sim.recording import rosbag2_metadata


MAGIC = b'\x89MCAP0\r\n'
RECORD_HEADER = struct.Struct('<BQ')  # opcode, content length
CHUNK_FIXED = struct.Struct('<QQQI')  # message start and end time, uncompressed size and crc
FOOTER = struct.Struct('<QQI')  # summary start, summary offset start, summary crc
RESYNC_BLOCK = 1024 * 1024  # [bytes] read at a time looking for the next intact chunk
MAX_RESYNC_CHUNK = 256 * 1024 * 1024  # [bytes] a candidate chunk longer is not read
MAX_COMPRESSION_NAME = 64  # [bytes] 'zstd', 'lz4' or '': a longer name is damage
CHUNK_SIZE = 768 * 1024  # [bytes] chunks of the repaired file: rosbag2's default
NAMES = {opcode.value: opcode.name.lower() for opcode in Opcode}
READERS = {
    Opcode.HEADER: Header.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.METADATA: Metadata.read,
    Opcode.ATTACHMENT: Attachment.read,
}
RECORD_ERRORS = (McapError, struct.error, ValueError, UnicodeDecodeError, EOFError, OverflowError)


def _read(opcode, content):
    """Parse the content of a record other than a chunk."""
    stream = ReadDataStream(BytesIO(content))
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, len(content))
    return READERS[opcode](stream)


class Scan:
    """
    The records of an MCAP file in file order, read past damage wherever it can be.

    Iterate records() once: Header, Schema, Channel, Message, Metadata and Attachment
    records, those inside chunks included. Afterwards damage is None for a
    complete file, or says where it is first truncated or corrupt; complete_chunks,
    partial_chunk_messages (from a chunk cut short), corrupt_chunks (failed their CRC,
    left out) and skipped (byte ranges passed over) count what was read; truncated
    says whether the damage is a missing end (a recording that was not closed) rather
    than corrupt bytes.

    A file with its footer is complete in length: a record that runs past the end of
    its data is corrupt (a damaged length field), not truncated; so is one that runs
    past the end of a file without footer when an intact chunk follows it. After corrupt bytes
    the scan resynchronises: on the next chunk of the summary's chunk index (its
    schemas and channels first), or else on the next record that is an intact chunk
    (its CRC checked); holes of a sparse file are skipped without being read.
    """

    def __init__(self, path):
        self.path = Path(path)
        self.damage = None
        self.truncated = False
        self.complete_chunks = 0
        self.partial_chunk_messages = 0
        self.corrupt_chunks = 0
        self.skipped = []  # (start, end) byte ranges passed over after corrupt bytes
        self._file = open_regular(self.path, MCAP_FILE)
        self.size = os.fstat(self._file.fileno()).st_size
        if self._file.read(len(MAGIC)) != MAGIC:
            self._file.close()
            raise InputFileError(
                f'{self.path} is not an MCAP file' + ('' if self.size else ' (it is empty)')
            )
        self.data_end, self._summary_start = self._footer()
        self._summary_records = None  # ([schemas, channels], [chunk offsets]) of the summary

    def records(self):
        """
        Yield the records in file order.

        A file with its summary yields the summary's schemas and channels right after
        its header, so that the messages of every intact chunk have theirs, even when
        the chunk that held them is damaged.
        """
        with self._file as file:
            offset, summary = len(MAGIC), self._summary(file)[0]
            while offset < self.size:
                found = self._next(file, offset)
                if found is None:
                    return
                offset, records = found
                yield from records
                yield from summary
                summary = ()
            self._say(f'is truncated: it ends at byte {self.size} without a footer')

    def _say(self, damage):
        if self.damage is None:
            self.damage = f'{self.path} {damage}'
            self.truncated = damage.startswith('is truncated')

    def _footer(self):
        """Return (end of the data, summary start) of a file with its footer, else (size, 0)."""
        footer_at = self.size - len(MAGIC) - RECORD_HEADER.size - FOOTER.size
        if footer_at < len(MAGIC):
            return self.size, 0
        self._file.seek(footer_at)
        tail = self._file.read()
        self._file.seek(len(MAGIC))
        opcode, length = RECORD_HEADER.unpack_from(tail)
        if opcode != Opcode.FOOTER or length != FOOTER.size or not tail.endswith(MAGIC):
            return self.size, 0
        summary_start = FOOTER.unpack_from(tail, RECORD_HEADER.size)[0]
        if len(MAGIC) < summary_start <= footer_at:
            return summary_start, summary_start
        return footer_at, 0

    def _next(self, file, offset):
        """Read the record at offset: (next offset, [records]) or None at the end."""
        header = file.read(RECORD_HEADER.size)
        if len(header) < RECORD_HEADER.size:
            self._say(f'is truncated: it ends at byte {self.size} inside a record header')
            return None
        opcode, length = RECORD_HEADER.unpack(header)
        name, end = NAMES.get(opcode), offset + RECORD_HEADER.size + length
        if name is None:
            self._say(f'is corrupt at byte {offset}: no MCAP record starts there')
            return self._resync(file, offset)
        limit = self.data_end if offset < self.data_end else self.size
        if opcode == Opcode.CHUNK:
            true_length = self._chunk_length(file, offset, limit)
            if true_length is not None and true_length != length:
                self._say(
                    f'is corrupt at byte {offset}: its chunk record says it is {length} bytes '
                    f'long, its content {true_length} (a damaged length field, read past)'
                )
                length, end = true_length, offset + RECORD_HEADER.size + true_length
            file.seek(offset + RECORD_HEADER.size)
        if end > limit and limit < self.size:
            self._say(
                f'is corrupt at byte {offset}: its {name} record says it is {length} bytes '
                f'long, past the end of the data at byte {limit} (the file has its footer)'
            )
            return self._resync(file, offset)
        if end > self.size and self._next_intact_chunk(file, offset):
            self._say(
                f'is corrupt at byte {offset}: its {name} record says it is {length} bytes '
                f'long, past the end of the file at byte {self.size}, but intact chunks follow'
            )
            return self._resync(file, offset)
        file.seek(offset + RECORD_HEADER.size)
        if end > self.size:
            self._say(
                f'is truncated: it ends at byte {self.size} inside a {name} record that starts '
                f'at byte {offset} and needs {end - self.size} more bytes'
            )
            if opcode == Opcode.CHUNK:
                return end, self._partial_chunk(file.read(), offset)
            return None
        if opcode == Opcode.FOOTER:
            file.seek(end)
            if file.read() != MAGIC:
                self._say(
                    f'is truncated: it ends at byte {self.size}, after its footer at byte '
                    f'{offset}, without the closing magic'
                )
            return None
        if opcode not in READERS and opcode not in (Opcode.CHUNK, Opcode.MESSAGE):
            file.seek(end)
            return end, []
        content = file.read(length)
        try:
            if opcode == Opcode.CHUNK:
                return end, self._chunk(content, offset)
            return end, [_read(opcode, content)]
        except RECORD_ERRORS as error:
            self._say(f'is corrupt at byte {offset} (a {name} record): {error}')
            return self._resync(file, offset)

    def _chunk(self, content, offset):
        chunk = Chunk.read(ReadDataStream(BytesIO(content)))
        stream, size = get_chunk_data_stream(chunk)
        data = stream.read(size)
        if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
            self.corrupt_chunks += 1
            self._say(f'is corrupt: the chunk at byte {offset} fails its CRC and is left out')
            return []
        self.complete_chunks += 1
        return self._inner(data, offset)

    def _partial_chunk(self, content, offset):
        """Return the records an uncompressed chunk cut short still holds."""
        fixed = CHUNK_FIXED.size
        if len(content) < fixed + 4:
            return []
        (name_length,) = struct.unpack_from('<I', content, fixed)
        data_start = fixed + 4 + name_length + 8
        compression = content[slice(fixed + 4, fixed + 4 + name_length)]
        if compression:
            self.damage += f' (its {compression.decode(errors="replace")} content is lost)'
            return []
        records = self._inner(content[data_start:], offset)
        self.partial_chunk_messages = sum(isinstance(r, Message) for r in records)
        return records

    def _inner(self, data, offset):
        """Return the records of chunk data, up to the first incomplete or damaged one."""
        records, start = [], 0
        while start + RECORD_HEADER.size <= len(data):
            opcode, length = RECORD_HEADER.unpack_from(data, start)
            content_start, start = start + RECORD_HEADER.size, start + RECORD_HEADER.size + length
            if start > len(data):
                break
            if opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.MESSAGE):
                try:
                    records.append(_read(opcode, data[content_start:start]))
                except RECORD_ERRORS as error:
                    self._say(f'is corrupt inside the chunk at byte {offset}: {error}')
                    break
        return records

    def _chunk_length(self, file, offset, limit):
        """
        Return the length a chunk record at offset has by its content, or None.

        A chunk's content says its own length (fixed fields, compression name, records
        length, records), which must end by limit: a damaged length field is read past.
        """
        file.seek(offset + RECORD_HEADER.size + CHUNK_FIXED.size)
        head = file.read(4)
        if len(head) < 4:
            return None
        (name_length,) = struct.unpack('<I', head)
        if name_length > MAX_COMPRESSION_NAME:
            return None
        file.seek(name_length, os.SEEK_CUR)
        tail = file.read(8)
        if len(tail) < 8:
            return None
        length = CHUNK_FIXED.size + 4 + name_length + 8 + struct.unpack('<Q', tail)[0]
        return length if offset + RECORD_HEADER.size + length <= limit else None

    # --- past corrupt bytes ---------------------------------------------------------------

    def _resync(self, file, offset):
        """After corrupt bytes at offset: (next offset, [records]) to go on from, or None."""
        found = self._next_indexed_chunk(file, offset) or self._next_intact_chunk(file, offset)
        if found is None:
            self.skipped.append((offset, self.data_end))
            return None
        self.skipped.append((offset, found[0]))
        file.seek(found[0])
        return found

    def _next_indexed_chunk(self, file, offset):
        """(offset of the first indexed chunk after offset, []), or None."""
        after = [start for start in self._summary(file)[1] if start > offset]
        return (min(after), []) if after else None

    def _summary(self, file):
        """
        Return ([schemas and channels], [chunk offsets]) of the summary section.

        Empty without a summary, or with a damaged one; read once.
        """
        if self._summary_records is not None:
            return self._summary_records
        self._summary_records = [], []
        if not self._summary_start:
            return self._summary_records
        position = file.tell()
        file.seek(self._summary_start)
        summary = file.read(self._summary_end() - self._summary_start)
        file.seek(position)
        records, chunks, start = [], [], 0
        while start + RECORD_HEADER.size <= len(summary):
            opcode, length = RECORD_HEADER.unpack_from(summary, start)
            content = summary[start + RECORD_HEADER.size:start + RECORD_HEADER.size + length]
            start += RECORD_HEADER.size + length
            try:
                if opcode == Opcode.CHUNK_INDEX:
                    index = ChunkIndex.read(ReadDataStream(BytesIO(content)))
                    chunks.append(index.chunk_start_offset)
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    records.append(_read(opcode, content))
            except RECORD_ERRORS:
                return self._summary_records  # the summary is damaged too
        self._summary_records = records, chunks
        return self._summary_records

    def _summary_end(self):
        """Return the byte where the summary section ends (the footer record's start)."""
        return self.size - len(MAGIC) - RECORD_HEADER.size - FOOTER.size

    def _next_intact_chunk(self, file, offset):
        """(offset of the next chunk record after offset whose CRC checks, []), or None."""
        descriptor, position = file.fileno(), offset + 1
        while position < self.data_end:
            raw = os.lseek(descriptor, 0, os.SEEK_CUR)  # where the buffered file left it
            try:
                position = os.lseek(descriptor, position, os.SEEK_DATA)  # past a sparse hole
            except OSError:  # ENXIO: nothing but a hole up to the end
                return None
            finally:
                os.lseek(descriptor, raw, os.SEEK_SET)
            block = os.pread(descriptor, min(RESYNC_BLOCK, self.data_end - position), position)
            at = block.find(bytes([Opcode.CHUNK]))
            while at >= 0:
                if self._chunk_at(file, position + at):
                    return position + at, []
                at = block.find(bytes([Opcode.CHUNK]), at + 1)
            position += max(len(block), 1)
        return None

    def _chunk_at(self, file, offset):
        """Return whether an intact chunk record (uncompressed, CRC checked) starts at offset."""
        file.seek(offset)
        header = file.read(RECORD_HEADER.size)
        if len(header) < RECORD_HEADER.size:
            return False
        length = RECORD_HEADER.unpack(header)[1]
        if not CHUNK_FIXED.size + 12 <= length <= min(MAX_RESYNC_CHUNK, self.data_end - offset):
            return False
        try:
            chunk = Chunk.read(ReadDataStream(BytesIO(file.read(length))))
            stream, size = get_chunk_data_stream(chunk)
            return bool(chunk.uncompressed_crc) and zlib.crc32(stream.read(size)) == (
                chunk.uncompressed_crc
            )
        except (*RECORD_ERRORS, LookupError, MemoryError):
            return False


def diagnose(path):
    """
    Read an MCAP file for damage, chunk CRCs included; return the Scan.

    Its damage is None for a complete, intact file.
    """
    scan = Scan(path)
    for _ in scan.records():
        pass
    return scan


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
