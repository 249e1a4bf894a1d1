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
mcap_index.fixed_rows: a topic's messages through the file's indexes, as the record read has them.

On bags of many chunks with other topics between the tick topics (messages of other
lengths), each topic's rows equal its messages in file order as BagReader gives them,
and tick_series reads the same through the indexes as record by record; a file whose
indexes cannot be trusted (truncated, a chunk failing its CRC, no statistics, messages
outside chunks, a topic of two channels, messages of two lengths) is declined (None),
and tick_series then says what the record read says.
"""

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
import numpy as np
import pytest
from valve_sim.core.errors import InputFileError
from valve_sim.core.model import STATE_NAMES
from valve_sim.recording import tick_bags
from valve_sim.recording.bag import BagReader, BagWriter, message_definition
from valve_sim.recording.mcap_index import fixed_rows
from valve_sim.recording.valve_topics import TICK_TOPICS, TickMessages, TOPIC_TYPES


AMBIENT = 101325.0
TOPICS = [f'/{topic}' for topic in TICK_TOPICS]
TICKS = 300


def write_ticks(path, chunk_size=4096, between=True):
    """Write a bag of TICKS ticks, small chunks, a /chatter message of another length between."""
    rng = np.random.default_rng(3)
    bag = BagWriter(path, chunk_size=chunk_size)
    channels = {topic: bag.add_topic('/' + topic, TOPIC_TYPES[topic]) for topic in TICK_TOPICS}
    chatter = bag.add_topic('/chatter', 'sensor_msgs/msg/JointState')
    for k in range(TICKS):
        stamp = 1_000_000_000 + k * 1_000_000
        for topic, data in TickMessages().fill(
                stamp, rng.normal(1e6, 1e5, len(STATE_NAMES)), 1e-5 * k, AMBIENT,
                tank_pressure=10.0 * k, relief=(1e-4, 8e-5, 2e-5, 1e-6)):
            if not (topic == 'pilot_pressure' and k == 11):  # one tick without it
                bag.write(channels[topic], data, stamp, stamp)
        if between:
            message = TickMessages(frame_prefix='x' * (k % 7)).fill(
                stamp, np.zeros(len(STATE_NAMES)), 0.0, AMBIENT)[-1][1]
            bag.write(chatter, message, stamp, stamp)
    bag.close()
    return path


def recorded(path, topic):
    return [bytes(message.data) for channel, _, message in BagReader(path).messages({topic})]


def record_by_record(path):
    original = tick_bags.fixed_rows
    tick_bags.fixed_rows = lambda *args: None
    try:
        return tick_bags.tick_series(path, ambient_pressure=AMBIENT)
    finally:
        tick_bags.fixed_rows = original


def assert_same_series(first, second):
    assert np.array_equal(first.stamps_ns, second.stamps_ns)
    assert np.array_equal(first.time, second.time)
    for name in second.columns:
        assert np.array_equal(first[name], second[name], equal_nan=True), name


def test_the_indexes_give_each_topics_messages_in_file_order(tmp_path):
    path = write_ticks(tmp_path / 'ticks.mcap')
    rows = fixed_rows(path, TOPICS + ['/not_there'])
    assert set(rows) == set(TOPICS)
    for topic in TOPICS:
        assert [row.tobytes() for row in rows[topic].data] == recorded(path, topic), topic
        assert rows[topic].schema.name == TOPIC_TYPES[topic[1:]]
    assert len(rows['/pilot_pressure'].data) == TICKS - 1
    assert fixed_rows(path, ['/chatter']) is None, 'messages of several lengths'
    assert_same_series(tick_bags.tick_series(path, ambient_pressure=AMBIENT),
                       record_by_record(path))


def test_a_file_the_indexes_cannot_vouch_for_is_declined(tmp_path):
    path = write_ticks(tmp_path / 'ticks.mcap')
    data = path.read_bytes()
    cut = tmp_path / 'cut.mcap'  # a recording killed mid-write: no footer, no summary
    cut.write_bytes(data[:len(data) * 2 // 3])
    assert fixed_rows(cut, TOPICS) is None
    assert len(tick_bags.tick_series(cut, ambient_pressure=AMBIENT)) > 0  # its chunks still

    with open(path, 'rb') as stream:
        first = make_reader(stream).get_summary().chunk_indexes[0]
    corrupt = bytearray(data)  # a byte of a message in the first chunk: it fails its CRC
    corrupt[first.chunk_start_offset + first.chunk_length - 5] ^= 0xFF
    (tmp_path / 'corrupt.mcap').write_bytes(bytes(corrupt))
    assert fixed_rows(tmp_path / 'corrupt.mcap', TOPICS) is None
    with pytest.raises(InputFileError, match='corrupt'):
        tick_bags.tick_series(tmp_path / 'corrupt.mcap', ambient_pressure=AMBIENT)


@pytest.mark.parametrize('kind', ['no statistics', 'no chunks', 'two channels'])
def test_files_of_other_writers_are_read_record_by_record(tmp_path, kind):
    path = tmp_path / f'{kind.replace(" ", "_")}.mcap'
    with open(path, 'wb') as stream:
        writer = Writer(stream, chunk_size=2048, compression=CompressionType.NONE,
                        use_statistics=kind != 'no statistics',
                        use_chunking=kind != 'no chunks')
        writer.start(profile='ros2', library='test')
        schemas = {topic: writer.register_schema(
            TOPIC_TYPES[topic], 'ros2msg', message_definition(TOPIC_TYPES[topic]).encode())
            for topic in TICK_TOPICS}
        channels = {topic: writer.register_channel(f'/{topic}', 'cdr', schemas[topic])
                    for topic in TICK_TOPICS}
        second = writer.register_channel('/supply_pressure', 'cdr', schemas['supply_pressure'])
        for k in range(40):
            stamp = 1_000_000_000 + k * 1_000_000
            for topic, data in TickMessages().fill(
                    stamp, np.full(len(STATE_NAMES), 1e6 + k), 1e-5, AMBIENT):
                channel = second if kind == 'two channels' and topic == 'supply_pressure' and (
                    k % 2) else channels[topic]
                writer.add_message(channel, stamp, data, stamp)
        writer.finish()
    assert fixed_rows(path, TOPICS) is None
    series = tick_bags.tick_series(path, ambient_pressure=AMBIENT)
    assert len(series) == 40 and not np.isnan(series['supply_pressure']).any()
    assert_same_series(series, record_by_record(path))
