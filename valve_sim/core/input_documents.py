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
YAML and JSON documents from files valve_sim reads: parsed within limits, checked.

A document can be hostile (docs/valve_node.md, "Files"): YAML whose aliases expand 500
bytes to gigabytes or that nests a thousand levels, a 400-digit number. Its text comes
from input_files (a regular file within its kind's size, UTF-8); here it is parsed
quickly, in bounded memory, to the document or one InputFileError line naming the
source and the line:

  YAML                 at most MAX_ALIASES aliases; the document, aliases expanded, at
                       most the kind's max_nodes nodes; nested at most MAX_DEPTH levels;
                       floats as ROS 2 reads them (YAML 1.2: 1e-3 is a float)
  JSON                 nested at most MAX_DEPTH levels; no NaN or Infinity
  numbers              integers that fit a float, finite floats
"""

import json
import math
import re
import sys

from valve_sim.core.errors import InputFileError
from valve_sim.core.input_files import check_size, read_text, shown
import yaml


MAX_DEPTH = 32  # nesting levels of a YAML or JSON document (a parameter file uses 5)
MAX_ALIASES = 100  # YAML aliases in one document
MAX_NUMBER_DIGITS = 400  # characters of an integer literal; more cannot fit a float anyway


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
        check_size(len(text.encode()), source, kind)
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

# The characters that open or close something: a bracket, or a string's quote.
_JSON_SPECIAL = re.compile(r'[\[\]{}"]')


def _brackets(text):
    """
    Yield the brackets of JSON text that lie outside its strings, in order.

    One pass and no state per character (a regex with a backtracking group kept ~140
    bytes a character; possessive quantifiers, which keep none, need Python 3.11). A
    string not closed runs to the end.
    """
    position = 0
    while (found := _JSON_SPECIAL.search(text, position)) is not None:
        position = found.end()
        if found.group() != '"':
            yield found.group()
            continue
        while (quote := text.find('"', position)) >= 0:  # the quote that ends the string
            escape = quote
            while escape > position and text[escape - 1] == '\\':
                escape -= 1
            position = quote + 1
            if (quote - escape) % 2 == 0:  # an even run of backslashes escapes none
                break
        else:
            return


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
    depth = brackets = 0
    for bracket in _brackets(text):
        if bracket in '[{':
            depth, brackets = depth + 1, brackets + 1
            if depth > MAX_DEPTH:
                raise InputFileError(f'{where}: nested more than {MAX_DEPTH} levels')
            if brackets > kind.max_nodes:
                raise InputFileError(
                    f'{where}: more than {kind.max_nodes} nested arrays and objects'
                )
        elif bracket in ']}':
            depth -= 1
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
