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
Serialized messages with fixed strings and sequence lengths, refilled in place.

valve_node publishes six messages every millisecond. Filling an rclpy message
and letting rclpy convert and serialize it costs about twice as much as
publishing bytes (a profile, docs/valve_node.md), so the tick messages
are kept as CDR bytes: built once, field by field, and then only the header
stamp and the float64 values are overwritten at their offsets.

The encoding is plain CDR as ROS 2 sends it (encapsulation CDR_LE, XCDR1):
every primitive aligned to its size, counted from the end of the 4-byte
encapsulation header; strings as uint32 length (with the NUL) + bytes + NUL;
sequences as uint32 count + elements.
"""

import struct

from valve_sim.core.errors import InputFileError


ENCAPSULATION = b'\x00\x01\x00\x00'  # CDR little endian, no options
STAMP = struct.Struct('<iI')  # builtin_interfaces/Time: sec, nanosec
STAMP_OFFSET = len(ENCAPSULATION)  # every message here begins with std_msgs/Header


class CdrMessage:
    """
    One message's CDR bytes, built field by field in definition order.

    The builders return the offset of what they wrote, for set_float64s() later.
    """

    def __init__(self, frame_id):
        """Start with a std_msgs/Header: stamp 0, frame_id (a str)."""
        self._data = bytearray(ENCAPSULATION)
        self._add('iI', 0, 0)
        self.string(frame_id)

    def _add(self, codes, *values):
        """Append values packed as struct codes (all of one size), aligned to that size."""
        size = struct.calcsize('<' + codes[-1])
        self._data += bytes(-(len(self._data) - len(ENCAPSULATION)) % size)
        offset = len(self._data)
        self._data += struct.pack('<' + codes, *values)
        return offset

    def string(self, text):
        encoded = text.encode() + b'\0'
        offset = self._add('I', len(encoded))
        self._data += encoded
        return offset

    def strings(self, texts):
        offset = self._add('I', len(texts))
        for text in texts:
            self.string(text)
        return offset

    def float64(self, value=0.0):
        return self._add('d', value)

    def float64s(self, count):
        """Append a sequence of count float64 (zeros); return the offset of the first element."""
        self._add('I', count)
        return self._add(f'{count}d', *[0.0] * count) if count else len(self._data)

    def set_stamp(self, sec, nanosec):
        STAMP.pack_into(self._data, STAMP_OFFSET, sec, nanosec)

    def set_float64s(self, offset, *values):
        struct.pack_into(f'<{len(values)}d', self._data, offset, *values)

    def bytes(self):  # noqa: A003  (named after the type it returns; a rename changes the API)
        """Return the message's bytes: what rclpy's Publisher.publish and the bag writer take."""
        return bytes(self._data)


FLOAT64 = struct.Struct('<d')
COUNT = struct.Struct('<I')  # a string's length (with its NUL) or a sequence's count


class CdrFields:
    """
    The fields of a little-endian CDR message, read in definition order.

    A reader of the few types valve_sim analyses live (std_msgs/Float64,
    sensor_msgs/FluidPressure, sensor_msgs/JointState) that skips rclpy's
    deserialisation into message objects: read_message() gives an object with the same
    attribute names. Raises struct.error or ValueError on bytes too short.
    """

    def __init__(self, data):
        self.data, self.offset = data, len(ENCAPSULATION)

    def _align(self, size):
        self.offset += -(self.offset - len(ENCAPSULATION)) % size

    def header(self):
        sec, nanosec = STAMP.unpack_from(self.data, self.offset)
        self.offset += STAMP.size
        frame_id = self.string()
        return _Fields(stamp=_Fields(sec=sec, nanosec=nanosec), frame_id=frame_id)

    def string(self):
        self._align(COUNT.size)
        (length,) = COUNT.unpack_from(self.data, self.offset)
        start = self.offset + COUNT.size
        self.offset = start + length
        if self.offset > len(self.data):
            raise InputFileError('a string runs past the end of the message')
        return bytes(self.data[start:self.offset - 1]).decode()

    def strings(self):
        self._align(COUNT.size)
        (count,) = COUNT.unpack_from(self.data, self.offset)
        self.offset += COUNT.size
        return [self.string() for _ in range(count)]

    def float64(self):
        self._align(FLOAT64.size)
        (value,) = FLOAT64.unpack_from(self.data, self.offset)
        self.offset += FLOAT64.size
        return value

    def float64s(self):
        self._align(COUNT.size)
        (count,) = COUNT.unpack_from(self.data, self.offset)
        self.offset += COUNT.size
        if not count:
            return ()
        self._align(FLOAT64.size)
        values = struct.unpack_from(f'<{count}d', self.data, self.offset)
        self.offset += count * FLOAT64.size
        return values


class _Fields:
    """A read message (or header, stamp): its fields as attributes."""

    def __init__(self, **fields):
        self.__dict__.update(fields)


def float_offsets(type_name, data):
    """
    Return ({field: [offset of each float64]}, joint names or None) of one message, or None.

    For sensor_msgs/FluidPressure (fluid_pressure) and sensor_msgs/JointState (position,
    velocity, effort); the layout of every message of a topic whose bytes other than
    these and the stamp (STAMP_OFFSET) are the same: its frame_id and joints.
    """
    fields = CdrFields(data)
    fields.header()
    if type_name == 'sensor_msgs/msg/FluidPressure':
        fields._align(FLOAT64.size)
        return {'fluid_pressure': [fields.offset]}, None
    if type_name != 'sensor_msgs/msg/JointState':
        return None
    names, offsets = fields.strings(), {}
    for field in ('position', 'velocity', 'effort'):
        fields._align(COUNT.size)
        (count,) = COUNT.unpack_from(data, fields.offset)
        fields.offset += COUNT.size
        if count:
            fields._align(FLOAT64.size)
        offsets[field] = [fields.offset + FLOAT64.size * k for k in range(count)]
        fields.offset += FLOAT64.size * count
    return offsets, names


def read_message(type_name, data):
    """
    Return the fields of a message of type_name ('pkg/msg/Type') from its CDR bytes.

    None if this reader does not read the type or the encoding (big-endian); raises
    struct.error or ValueError on bytes too short for the type.
    """
    if len(data) < len(ENCAPSULATION) or data[1] != 1:
        return None
    fields = CdrFields(data)
    if type_name == 'std_msgs/msg/Float64':
        return _Fields(data=fields.float64())
    if type_name == 'sensor_msgs/msg/FluidPressure':
        header = fields.header()
        return _Fields(header=header, fluid_pressure=fields.float64(), variance=fields.float64())
    if type_name == 'sensor_msgs/msg/JointState':
        header = fields.header()
        return _Fields(header=header, name=fields.strings(), position=fields.float64s(),
                       velocity=fields.float64s(), effort=fields.float64s())
    return None
