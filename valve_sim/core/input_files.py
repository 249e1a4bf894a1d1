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
  YAML                 at most MAX_ALIASES aliases; the document, aliases expanded, at
                       most the kind's max_nodes nodes; nested at most MAX_DEPTH levels;
                       floats as ROS 2 reads them (YAML 1.2: 1e-3 is a float)
  JSON                 nested at most MAX_DEPTH levels; no NaN or Infinity
  numbers              integers that fit a float, finite floats

Each kind's schema is checked by its own reader (fault_schedule.parse_schedule,
parameters.read_parameter_file, ...), which names the key at fault. What a caller
checks is what it applies: it parses the bytes it read once, never the file again.
"""

from dataclasses import dataclass
from itertools import accumulate
import json
import math
import os
import re
import reprlib
import stat
import sys

from valve_sim.core.errors import InputFileError
import yaml


MiB = 1024 * 1024
MAX_DEPTH = 32  # nesting levels of a YAML or JSON document (a parameter file uses 5)
MAX_ALIASES = 100  # YAML aliases in one document
MAX_NUMBER_DIGITS = 400  # characters of an integer literal; more cannot fit a float anyway


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
        _check_size(info.st_size, path, kind)
        os.set_blocking(descriptor, True)
        return os.fdopen(descriptor, 'rb')
    except BaseException:
        os.close(descriptor)
        raise


def _check_size(size, path, kind):
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
    _check_size(len(data), path, kind)  # it grew while being read
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


# --- YAML -------------------------------------------------------------------------------------

_BASE_LOADER = yaml.CSafeLoader if getattr(yaml, '__with_libyaml__', False) else yaml.SafeLoader


class _Loader(_BASE_LOADER):
    """SafeLoader (libyaml's where PyYAML has it) reading 1e-3 as a float, as ROS 2 does."""


_Loader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+$'),
    list('-+0123456789.'),
)
_COLLECTION_START = (yaml.SequenceStartEvent, yaml.MappingStartEvent)
_COLLECTION_END = (yaml.SequenceEndEvent, yaml.MappingEndEvent)
INT_TAG = 'tag:yaml.org,2002:int'
FLOAT_TAG = 'tag:yaml.org,2002:float'


def read_yaml(path, kind, stream=None):
    """Return the YAML document of a file (None if empty), read once and checked."""
    return parse_yaml(read_text(path, kind, stream), kind, path)


def parse_yaml(text, kind, source):
    """
    Return the YAML document of text from source (a file, or a record of one).

    Checked before it is built (aliases, nodes, depth) and as it is built (numbers).
    Raises InputFileError naming source and the line.
    """
    if kind.max_bytes is not None and len(text) > kind.max_bytes:
        _check_size(len(text.encode()), source, kind)
    where = f'{kind.name} {source}'
    try:
        _scan_events(text, kind, where)
        loader = _Loader(text)
        try:
            node = loader.get_single_node()
            if node is None:
                return None
            _check_numbers(node, loader, where)
            return loader.construct_document(node)
        finally:
            loader.dispose()
    except yaml.MarkedYAMLError as error:
        mark = error.problem_mark or error.context_mark
        at = f'line {mark.line + 1}, column {mark.column + 1}: ' if mark else ''
        problem = ' '.join(' '.join(filter(None, (error.context, error.problem))).split())
        raise InputFileError(f'{where} is not valid YAML: {at}{problem}') from None
    except yaml.YAMLError as error:  # one line: the reader's message spans two
        problem = ' '.join(str(error).split())
        raise InputFileError(f'{where} is not valid YAML: {problem}') from None
    except (ValueError, OverflowError) as error:  # a scalar the constructor cannot build
        if isinstance(error, InputFileError):
            raise
        raise InputFileError(f'{where}: a value cannot be read: {error}') from None


def _scan_events(text, kind, where):
    """Refuse too many aliases, a document too large once expanded, or nesting too deep."""
    anchors, open_sizes, aliases, nodes = {}, [], 0, 0
    for event in yaml.parse(text, Loader=_Loader):
        line = getattr(event.start_mark, 'line', -1) + 1
        if isinstance(event, _COLLECTION_START):
            if len(open_sizes) >= MAX_DEPTH:
                raise InputFileError(f'{where}: line {line}: nested more than {MAX_DEPTH} levels')
            if event.anchor is not None:
                anchors[event.anchor] = None  # open: an alias to it would contain itself
            open_sizes.append([event.anchor, 1])
            size = 1
        elif isinstance(event, _COLLECTION_END):
            anchor, total = open_sizes.pop()
            if anchor is not None:
                anchors[anchor] = total
            if open_sizes:
                open_sizes[-1][1] += total
            continue
        elif isinstance(event, yaml.ScalarEvent):
            size = 1
            if event.anchor is not None:
                anchors[event.anchor] = 1
        elif isinstance(event, yaml.AliasEvent):
            aliases += 1
            if aliases > MAX_ALIASES:
                raise InputFileError(
                    f'{where}: line {line}: more than {MAX_ALIASES} YAML aliases'
                )
            size = anchors.get(event.anchor, 1)
            if size is None:
                raise InputFileError(
                    f'{where}: line {line}: alias *{event.anchor} refers to a node that '
                    'contains it'
                )
        else:
            continue
        nodes += size
        if nodes > kind.max_nodes:
            raise InputFileError(
                f'{where}: line {line}: the document, its aliases expanded, has more than '
                f'{kind.max_nodes} nodes'
            )
        if open_sizes and not isinstance(event, _COLLECTION_START):
            open_sizes[-1][1] += size


def _check_numbers(root, loader, where):
    """Refuse integers that do not fit a float and floats that are not finite."""
    seen, pending = set(), [root]
    while pending:
        node = pending.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        if isinstance(node, yaml.ScalarNode):
            if node.tag == INT_TAG:
                if len(node.value) > MAX_NUMBER_DIGITS:
                    _refuse_number(node, where, f'a {len(node.value)}-digit integer')
                if not abs(loader.construct_yaml_int(node)) <= sys.float_info.max:
                    _refuse_number(node, where, f'integer {shown(node.value)}')
            elif node.tag == FLOAT_TAG and not math.isfinite(loader.construct_yaml_float(node)):
                _refuse_number(node, where, shown(node.value))
        elif isinstance(node, yaml.SequenceNode):
            pending.extend(node.value)
        elif isinstance(node, yaml.MappingNode):
            pending.extend(item for pair in node.value for item in pair)


def _refuse_number(node, where, what):
    raise InputFileError(
        f'{where}: line {node.start_mark.line + 1}: {what} is not a finite number that fits '
        'a float'
    )


# --- JSON -------------------------------------------------------------------------------------

_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"', re.DOTALL)
_NOT_BRACKET = re.compile(r'[^\[\]{}]')


class _BadNumber(ValueError):
    """A JSON number literal that is not a finite float."""


def read_json(path, kind):
    """Return the JSON document of a file, read once and checked."""
    return parse_json(read_text(path, kind), kind, path)


def parse_json(text, kind, source):
    """
    Return the JSON document of text from source; InputFileError naming source and line.

    Nested at most MAX_DEPTH levels (checked before parsing), no NaN or Infinity,
    numbers that fit a float, at most kind.max_nodes values.
    """
    where = f'{kind.name} {source}'
    brackets = _NOT_BRACKET.sub('', _JSON_STRING.sub('', text))
    depth = max(accumulate(1 if c in '[{' else -1 for c in brackets), default=0)
    if depth > MAX_DEPTH:
        raise InputFileError(f'{where}: nested more than {MAX_DEPTH} levels')
    if len(brackets) // 2 > kind.max_nodes:
        raise InputFileError(f'{where}: more than {kind.max_nodes} nested arrays and objects')
    try:
        return json.loads(
            text, parse_constant=_refuse_constant, parse_float=_float, parse_int=_int
        )
    except _BadNumber as error:
        literal = str(error)
        line = text.count('\n', 0, max(text.find(literal), 0)) + 1
        raise InputFileError(
            f'{where}: line {line}: {shown(literal)} is not a finite number that fits a float'
        ) from None
    except json.JSONDecodeError as error:
        raise InputFileError(
            f'{where} is not valid JSON: line {error.lineno}, column {error.colno}: {error.msg}'
        ) from None


def _refuse_constant(literal):
    raise _BadNumber(literal)


def _float(literal):
    value = float(literal)
    if not math.isfinite(value):
        raise _BadNumber(literal)
    return value


def _int(literal):
    if len(literal) > MAX_NUMBER_DIGITS or not abs(int(literal)) <= sys.float_info.max:
        raise _BadNumber(literal)
    return int(literal)


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
