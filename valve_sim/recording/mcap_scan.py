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
Reading a damaged MCAP file record by record: where it is damaged, what it still holds.

A recording killed mid-write (kill -9, a full disk, a power cut) ends inside a
record and has no summary, so seeking readers (rosbags, the mcap library's
indexed reader, rosbag2) refuse it. Scan reads the file record by record, past
damage wherever it can (the records of a chunk cut short too, if the chunk is
uncompressed, as rosbag2's and ours are; on after corrupt bytes at the next intact
chunk); one record is in memory at a time. diagnose() says where a file is
truncated or corrupt. recovery writes what a Scan yields to a new file; bag reads
recordings through it.
"""

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
from valve_sim.core.errors import InputFileError
from valve_sim.core.input_files import MCAP_FILE, open_regular


MAGIC = b'\x89MCAP0\r\n'
RECORD_HEADER = struct.Struct('<BQ')  # opcode, content length
# a message record: opcode, length, channel id, sequence, log time, publish time, data
MESSAGE_FIXED = struct.Struct('<BQHIQQ')
INDEX_FIXED = struct.Struct('<BQHI')  # a message index: opcode, length, channel id, bytes
CHUNK_FIXED = struct.Struct('<QQQI')  # message start and end time, uncompressed size and crc
FOOTER = struct.Struct('<QQI')  # summary start, summary offset start, summary crc
RESYNC_BLOCK = 1024 * 1024  # [bytes] read at a time looking for the next intact chunk
MAX_RESYNC_CHUNK = 256 * 1024 * 1024  # [bytes] a candidate chunk longer is not read
MAX_COMPRESSION_NAME = 64  # [bytes] 'zstd', 'lz4' or '': a longer name is damage
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
