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
Every file valve_sim reads, read one way: bounded, checked, and once.

The files come from users and from crashed runs, so each can be anything: a FIFO
that blocks a reader for ever, /dev/zero, a 12 MB schedule, bytes that are not text,
YAML whose aliases expand 500 bytes to gigabytes or that nests a thousand levels, a
400-digit number. Whatever it is, reading it ends quickly, in bounded memory, with
the document or one InputFileError line naming the file and the line:

  regular files only   opened non-blocking and checked with fstat before a byte is read
                       (no FIFO, device, directory or socket)
  size                 at most the kind's max_bytes (KINDS; docs/valve_node.md, "Files")
  text                 UTF-8 (a byte-order mark is allowed)
  YAML, JSON           documents parsed within limits (input_documents)

This module reads the bytes and the text; input_documents parses them as YAML or
JSON. Each kind's schema is checked by its own reader (fault_schedule.parse_schedule,
parameters.read_parameter_file, ...), which names the key at fault. What a caller
checks is what it applies: it parses the bytes it read once, never the file again.
"""

from dataclasses import dataclass
import os
import reprlib
import stat

from valve_sim.core.errors import InputFileError


MiB = 1024 * 1024


@dataclass(frozen=True)
class FileKind:
    """
    A kind of file valve_sim reads: its name (for messages) and its limits.

    max_bytes: the largest file accepted (None: any size, e.g. an MCAP bag);
    max_nodes: the most YAML or JSON nodes (scalars and collections) of its document,
    aliases expanded.
    """

    name: str
    max_bytes: int = None
    max_nodes: int = 100_000

    def limits(self):
        """Return the limits as text, for --help and the docs."""
        return f'at most {size_text(self.max_bytes)}' if self.max_bytes else 'any size'


PARAMETER_FILE = FileKind('parameter file', 1 * MiB)
FAULT_SCHEDULE = FileKind('fault schedule', 1 * MiB, 200_000)
MAX_EVENTS = 10_000  # events of one fault schedule: 10 a second for over 16 minutes
TARGET_MEASURES = FileKind('target measures file', 64 * 1024, 10_000)
BAG_METADATA = FileKind('rosbag2 metadata file', 4 * MiB, 500_000)
BAG_RECORD = FileKind('metadata record', 4 * MiB, 500_000)  # YAML inside an MCAP file
STUDY_RESULTS = FileKind('study results file', 4096 * MiB)  # JSON lines, STUDY_ROW each
STUDY_ROW = FileKind('study results row', 64 * MiB, 2_000_000)
MEASURES_FILE = FileKind('step measures file', 64 * MiB, 2_000_000)
MCAP_FILE = FileKind('MCAP file')
SCENARIO_FILE = FileKind('scenario', 1 * MiB, 200_000)  # valve-sim scenario (docs/scenarios.md)
INPUT_CSV = FileKind('input CSV file', 64 * MiB)  # a scenario input's recorded column
KINDS = (
    PARAMETER_FILE,
    FAULT_SCHEDULE,
    TARGET_MEASURES,
    BAG_METADATA,
    BAG_RECORD,
    STUDY_RESULTS,
    STUDY_ROW,
    MEASURES_FILE,
    MCAP_FILE,
    SCENARIO_FILE,
    INPUT_CSV,
)
FILE_TYPES = (
    (stat.S_ISDIR, 'a directory'),
    (stat.S_ISFIFO, 'a FIFO'),
    (stat.S_ISCHR, 'a character device'),
    (stat.S_ISBLK, 'a block device'),
    (stat.S_ISSOCK, 'a socket'),
)
_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = 60
_SHORT.maxlist = _SHORT.maxdict = _SHORT.maxtuple = _SHORT.maxset = 4
_SHORT.maxlevel = 2


def shown(value):
    """Return a bounded repr of a value from a file, for an error message."""
    return _SHORT.repr(value)


def size_text(count):
    """Return a byte count as text: '512 bytes', '64 KiB', '1 MiB', '12.0 MiB'."""
    for unit, scale in (('GiB', 1024 * MiB), ('MiB', MiB), ('KiB', 1024)):
        if count >= scale:
            number = count / scale
            return f'{number:.0f} {unit}' if number == int(number) else f'{number:.1f} {unit}'
    return f'{count} bytes'


def open_regular(path, kind):
    """
    Open path for reading in binary, if it is a regular file within kind's size limit.

    Opened non-blocking, so a FIFO without a writer cannot block, and checked with
    fstat before anything is read. Returns the open file; raises InputFileError.
    """
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    except OSError as error:
        raise InputFileError(f'cannot read {kind.name} {path}: {error.strerror}') from error
    except ValueError:  # a NUL character in the name: no file can have it
        raise InputFileError(
            f'cannot read {kind.name} {shown(str(path))}: a NUL in its name'
        ) from None
    try:
        info = os.fstat(descriptor)
        if not stat.S_ISREG(info.st_mode):
            what = next((name for test, name in FILE_TYPES if test(info.st_mode)), 'special')
            raise InputFileError(
                f'cannot read {kind.name} {path}: it is {what}, not a regular file'
            )
        check_size(info.st_size, path, kind)
        os.set_blocking(descriptor, True)
        return os.fdopen(descriptor, 'rb')
    except BaseException:
        os.close(descriptor)
        raise


def check_size(size, path, kind):
    """Refuse size [bytes] of path (a file, or text from one) past kind's max_bytes."""
    if kind.max_bytes is not None and size > kind.max_bytes:
        raise InputFileError(
            f'cannot read {kind.name} {path}: it holds {size_text(size)}, more than the '
            f'{size_text(kind.max_bytes)} a {kind.name} may hold'
        )


def read_bytes(path, kind, stream=None):
    """
    Return the bytes of a regular file within kind's size limit (read once).

    stream: path already opened by open_regular() (then read from there and closed).
    """
    with stream or open_regular(path, kind) as opened:
        try:
            data = opened.read(kind.max_bytes + 1 if kind.max_bytes else -1)
        except OSError as error:
            raise InputFileError(f'cannot read {kind.name} {path}: {error.strerror}') from error
    check_size(len(data), path, kind)  # it grew while being read
    return data


def decoded(data, kind, source):
    """Return bytes as text if they are UTF-8 (a leading byte-order mark dropped)."""
    try:
        return data.decode('utf-8-sig')
    except UnicodeDecodeError as error:
        line = data.count(b'\n', 0, error.start) + 1
        column = error.start - (data.rfind(b'\n', 0, error.start) + 1) + 1
        raise InputFileError(
            f'{kind.name} {source} is not UTF-8 text: byte 0x{data[error.start]:02x} at line '
            f'{line}, column {column}'
        ) from None


def read_text(path, kind, stream=None):
    """Return the text of a regular UTF-8 file within kind's size limit (stream: read_bytes)."""
    return decoded(read_bytes(path, kind, stream), kind, path)


def json_lines(path, kind, row_kind):
    """
    Yield (line number, text) of each complete line of a JSON-lines file.

    The file is a regular file within kind's limit; each line within row_kind's
    (max_bytes). A last line without its newline (torn by a crash) is not yielded.
    """
    with open_regular(path, kind) as stream:
        number = 0
        while True:
            number += 1
            line = stream.readline(row_kind.max_bytes + 2)
            if not line.endswith(b'\n'):
                if len(line) > row_kind.max_bytes:
                    raise InputFileError(
                        f'{kind.name} {path}: line {number} is longer than '
                        f'{size_text(row_kind.max_bytes)}'
                    )
                return
            yield number, decoded(line, kind, f'{path}, line {number},')
