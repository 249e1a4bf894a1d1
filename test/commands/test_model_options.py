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

"""The README's sentence on which commands take the model's options, held to the parsers."""

import argparse
from pathlib import Path
import re

from valve_sim.commands.cli import build_parser, SUBCOMMANDS

README = Path(__file__).resolve().parents[2] / 'README.md'
MODEL_OPTIONS = {'--params', '--set', '--preset-pressure'}


def options_of(parser):
    """{(command path): option strings} of a parser and its nested subcommands."""
    found, own = {}, set()
    for action in parser._actions:
        own |= set(action.option_strings)
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.update({(name, *path): options for path, options in options_of(sub).items()})
    found[()] = own
    return found


def test_the_readme_names_exactly_the_commands_that_take_the_model_options():
    text = ' '.join(README.read_text().split())
    sentence = re.search(r'The commands that run the model \(([^)]*)\) take '
                         r'`--params FILE\.yaml`, `--set NAME=VALUE` \([^)]*\) and '
                         r'`--preset-pressure 7MPa`', text)
    assert sentence, 'the README no longer says which commands take --params, --set, ...'
    named = {name.strip() for name in sentence.group(1).split(',')}
    taking, lacking = set(), set()
    for command in SUBCOMMANDS:
        (subcommands,) = [a for a in build_parser([command])._actions
                          if isinstance(a, argparse._SubParsersAction)]
        for path, options in options_of(subcommands.choices[command]).items():
            (taking if MODEL_OPTIONS <= options else lacking).add(' '.join((command, *path)))
            assert not (MODEL_OPTIONS & options) or MODEL_OPTIONS <= options, (command, path)
    assert named == taking
    # and no nested subcommand of a named command lacks them (scenario run/check take none)
    assert not {c for c in lacking if c.split()[0] in named}
