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
A complete MCAP file's messages of a few topics as rows of bytes, through its indexes.

Reading a long lockstep run's bag record by record (mcap_scan.Scan) parses every one of
its half a million records in Python, most of them of topics a reader does not want.
A complete file (footer, summary with statistics and a chunk index per chunk, as
bag.BagWriter and rosbag2 write) says where each chunk is and, in its message index
records, where each channel's messages are in it: fixed_rows() takes a topic's
messages out of each chunk with numpy, as rows of one length (valve_node's messages of
a topic have one layout), in file order. Every chunk is read and its CRC checked, as
the record-by-record read does. Anything else (no summary, a truncated or damaged
file, messages not all in indexed chunks, a topic of two channels or of messages of
different lengths) gives None: the record-by-record read then decides, and says what
is wrong with the file.
"""

from io import BytesIO
import zlib

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import get_chunk_data_stream
import numpy as np
from valve_sim.core.input_files import MCAP_FILE, open_regular
from valve_sim.recording.mcap_scan import (
    INDEX_FIXED, MESSAGE_FIXED, RECORD_ERRORS, RECORD_HEADER)


class Rows:
    """One topic's messages: its channel and schema, and data (uint8 rows, file order; some)."""

    def __init__(self, channel, schema):
        self.channel, self.schema, self.parts = channel, schema, []

    @property
    def data(self):
        return np.concatenate(self.parts)


def fixed_rows(path, topics):
    """
    Return {topic: Rows} of the topics an MCAP file holds, read through its indexes, or None.

    None where the indexes cannot be trusted to give every message of those topics, or
    where a topic's messages differ in length (module docstring).
    """
    try:
        with open_regular(path, MCAP_FILE) as file:
            return _read(file, set(topics))
    except (*RECORD_ERRORS, LookupError, MemoryError):
        return None


def _read(file, topics):
    summary = make_reader(file).get_summary()
    if summary is None or summary.statistics is None:
        return None
    wanted = {}  # channel id: Rows
    for channel in summary.channels.values():
        if channel.topic in topics:
            schema = summary.schemas.get(channel.schema_id)
            if schema is None or channel.message_encoding != 'cdr':
                return None
            wanted[channel.id] = Rows(channel, schema)
    if len({rows.channel.topic for rows in wanted.values()}) != len(wanted):
        return None  # a topic of two channels: the record-by-record read merges them
    counts = dict.fromkeys(wanted, 0)
    for index in sorted(summary.chunk_indexes, key=lambda index: index.chunk_start_offset):
        file.seek(index.chunk_start_offset)
        raw = file.read(index.chunk_length + index.message_index_length)
        data = _chunk_data(raw[:index.chunk_length])
        if data is None:
            return None
        for channel_id, offset in index.message_index_offsets.items():
            if channel_id in wanted:
                start = offset - index.chunk_start_offset
                if not index.chunk_length <= start < len(raw):
                    return None  # not among the message indexes after the chunk
                rows = _channel_rows(data, raw[start:], channel_id)
                if rows is None:
                    return None
                if len(rows):
                    wanted[channel_id].parts.append(rows)
                    counts[channel_id] += len(rows)
    totals = summary.statistics.channel_message_counts
    if any(totals.get(channel_id, 0) != count for channel_id, count in counts.items()):
        return None  # messages outside the indexed chunks
    if any(len({part.shape[1] for part in rows.parts}) > 1 for rows in wanted.values()):
        return None
    return {rows.channel.topic: rows for rows in wanted.values() if rows.parts}


def _chunk_data(raw):
    """Return a chunk record's records as a uint8 array (its CRC checked), or None."""
    opcode, length = RECORD_HEADER.unpack_from(raw)
    if opcode != Opcode.CHUNK or RECORD_HEADER.size + length != len(raw):
        return None
    chunk = Chunk.read(ReadDataStream(BytesIO(raw[RECORD_HEADER.size:])))
    stream, size = get_chunk_data_stream(chunk)
    data = stream.read(size)
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        return None
    return np.frombuffer(data, np.uint8)


def _channel_rows(data, raw_index, channel_id):
    """Return a channel's messages in a chunk's data as uint8 rows (file order), or None."""
    opcode, length, index_channel, size = INDEX_FIXED.unpack_from(raw_index)
    if (opcode != Opcode.MESSAGE_INDEX or index_channel != channel_id
            or INDEX_FIXED.size + size > RECORD_HEADER.size + length or size % 16):
        return None
    pairs = np.frombuffer(raw_index, '<u8', size // 8, INDEX_FIXED.size).reshape(-1, 2)
    offsets = np.sort(pairs[:, 1]).astype(np.int64)
    if not offsets.size:
        return offsets
    if offsets[-1] + MESSAGE_FIXED.size > data.size:
        return None
    heads = data[offsets[:, None] + np.arange(MESSAGE_FIXED.size)]
    fixed = np.ascontiguousarray(heads).view(np.dtype([
        ('opcode', 'u1'), ('length', '<u8'), ('channel', '<u2'), ('sequence', '<u4'),
        ('log_time', '<u8'), ('publish_time', '<u8')])).ravel()
    lengths = fixed['length']
    if ((fixed['opcode'] != Opcode.MESSAGE).any() or (fixed['channel'] != channel_id).any()
            or (lengths != lengths[0]).any()
            or offsets[-1] + RECORD_HEADER.size + int(lengths[0]) > data.size):
        return None
    width = int(lengths[0]) - (MESSAGE_FIXED.size - RECORD_HEADER.size)
    if width < 0:
        return None
    return data[offsets[:, None] + (MESSAGE_FIXED.size + np.arange(width))]
