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
Hostile inputs, by class: the files, documents and bytes a reader must survive.

Shared by the reader tests (test_input_files.py), the node tests (test_hostile_node.py)
and bench/attack.py. Each table maps a name to a function of a path that puts the
input there (make_file), or to the text or bytes of a document:

  FILES        what is at the path: a FIFO, a directory, a device, nothing, a sparse
               2 GiB file (no YAML or JSON reader may even start reading these)
  YAML_TEXTS   YAML that must be refused whatever it claims to be: alias bombs (lists,
               mappings, merge keys), an alias that contains itself, 100 levels of nesting,
               numbers that do not fit a float, bytes that are not UTF-8
  JSON_TEXTS   the same for JSON: deep nesting, NaN and Infinity, 1e400, huge integers
mutations() gives seeded random damage of a valid file's bytes, for fuzzing;
make_sparse_mcap() and bag_with_inf_pressure() make the hostile recordings.
"""

import os
import random


def list_bomb(key='events', levels=9, width=9):
    """Return YAML whose aliases expand to width^levels strings, under key."""
    lines = ['a: &a [' + ', '.join(['x'] * width) + ']']
    for level in range(1, levels):
        previous, name = chr(ord('a') + level - 1), chr(ord('a') + level)
        lines.append(f'{name}: &{name} [' + ', '.join([f'*{previous}'] * width) + ']')
    return '\n'.join(lines) + f'\n{key}: *{name}\n'


def dict_bomb(key='events', levels=9, width=9):
    """Return the mapping form of list_bomb()."""
    lines = ['a: &a {' + ', '.join(f'k{i}: x' for i in range(width)) + '}']
    for level in range(1, levels):
        previous, name = chr(ord('a') + level - 1), chr(ord('a') + level)
        items = ', '.join(f'k{i}: *{previous}' for i in range(width))
        lines.append(f'{name}: &{name} {{{items}}}')
    return '\n'.join(lines) + f'\n{key}: [*{name}]\n'


def merge_bomb(levels=9, width=9):
    """Return YAML whose merge keys (<<) copy mappings width^levels times."""
    lines = ['a0: &a0 {' + ', '.join(f'k{i}: x' for i in range(width)) + '}']
    for level in range(1, levels):
        merged = ', '.join(f'*a{level - 1}' for _ in range(width))
        lines.append(f'a{level}: &a{level} {{<<: [{merged}], n{level}: 1}}')
    return '\n'.join(lines) + '\n'


YAML_TEXTS = {
    'random bytes': os.urandom(4096),
    'invalid UTF-8 after text': b'events:\n  - t: 0.1\n    set: {\xff\xfe: 1}\n',
    'a list alias bomb': list_bomb(),
    'a dict alias bomb': dict_bomb(),
    'a merge-key bomb': merge_bomb(),
    'an alias that contains itself': 'events: &e [*e]\n',
    'lists nested 100 levels': 'events: ' + '[' * 100 + ']' * 100 + '\n',
    'mappings nested 100 levels': 'events: ' + '{a: ' * 100 + '1' + '}' * 100 + '\n',
    'block lists nested 100 levels': ''.join('  ' * i + '-\n' for i in range(100)),
    'a 400-digit integer': f'events:\n  - t: {"9" * 400}\n    set: {{x: 1}}\n',
    'a 5000-digit integer': f'x: {"1" * 5000}\n',
    'a hex integer beyond a float': f'x: 0x{"f" * 300}\n',
    'a float of 1e400': 'events:\n  - t: 1e400\n    set: {x: 1}\n',
    'a float of -.inf': 'x: -.inf\n',
    'a float of .nan': 'x: .nan\n',
    'a NUL character': 'x: "a\0b"\n\0\n',
    'two documents': 'x: 1\n---\ny: 2\n',
    'an unhashable key': '? [a, b]\n: 1\n',
    'a python tag': 'x: !!python/object/apply:os.system ["true"]\n',
    'a broken flow list': 'events: [1, 2\n',
}
JSON_TEXTS = {
    'random bytes': os.urandom(4096),
    'arrays nested 100,000 levels': '[' * 100_000 + ']' * 100_000,
    'objects nested 1000 levels': '{"a": ' * 1000 + '1' + '}' * 1000,
    'NaN': '{"T_1_ms": NaN}',
    'Infinity': '{"T_1_ms": {"value": Infinity}}',
    '-Infinity': '{"T_1_ms": -Infinity}',
    '1e400': '{"T_1_ms": 1e400}',
    'a 5000-digit integer': '{"T_1_ms": ' + '7' * 5000 + '}',
    'broken': '{"T_1_ms": [1, 2',
    'a string, not an object': '"T_1_ms"',
}


def make_fifo(path):
    os.mkfifo(path)


def make_directory(path):
    path.mkdir()


def make_device(path):
    path.symlink_to('/dev/zero')


def make_nothing(path):
    pass


def make_sparse(path):
    with open(path, 'wb') as stream:
        stream.truncate(2 * 1024**3)


def make_sparse_mcap(path):
    """Write the MCAP magic, then a 2 GiB sparse hole (a file preallocated and never written)."""
    with open(path, 'wb') as stream:
        stream.write(b'\x89MCAP0\r\n')
        stream.truncate(2 * 1024**3)


def bag_with_inf_pressure(path):
    """Write a simulated step's bag whose supply pressure reads inf from 0.3 s (0.1 s after it)."""
    import numpy as np
    from valve_sim.core.parameters import load_parameters
    from valve_sim.core.simulation import FlowStep, simulate
    from valve_sim.recording.valve_topics import write_simulation_bag

    waveforms = simulate(load_parameters().params, FlowStep(step_time=0.1, end_time=1.2),
                         record_interval=1e-3)
    readings = waveforms.states[:, :4] + 101325.0
    readings[300:, 0] = np.inf
    write_simulation_bag(path, waveforms, readings=readings, start_time_ns=1_700_000_000 * 10**9)


FILES = {
    'a FIFO': make_fifo,
    'a directory': make_directory,
    '/dev/zero': make_device,
    'a missing file': make_nothing,
    'a sparse 2 GiB file': make_sparse,
}


def make_file(path, content):
    """Put content (text, bytes, or a FILES function) at path."""
    if callable(content):
        content(path)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)


def mutations(data, count, seed=0):
    """
    Yield count damaged copies of data (bytes), seeded.

    The damage: bits flipped, bytes replaced, stretches cut, repeated or inserted.
    """
    rng = random.Random(seed)
    for _ in range(count):
        damaged = bytearray(data)
        for _ in range(rng.randint(1, 8)):
            kind, at = rng.randrange(5), rng.randrange(max(len(damaged), 1))
            if kind == 0 and damaged:
                damaged[at] ^= 1 << rng.randrange(8)
            elif kind == 1 and damaged:
                damaged[at] = rng.randrange(256)
            elif kind == 2:
                del damaged[at:at + rng.randint(1, 64)]
            elif kind == 3:
                damaged[at:at] = damaged[at:at + rng.randint(1, 256)] * rng.randint(1, 8)
            else:
                damaged[at:at] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
        yield bytes(damaged)
