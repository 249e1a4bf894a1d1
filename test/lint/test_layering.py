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
The wings of valve_sim import only downward, and only ros (and the testing kit) use rclpy.

Reads every module's imports with ast (nothing is executed), module-level and
inside functions alike. The commands import the library and commands/options.py,
never another subcommand (cli, the entry point, finds them by name).
"""

import ast
from pathlib import Path

import pytest


PACKAGE = Path(__file__).resolve().parents[2] / 'valve_sim'
WINGS = ['core', 'fmu', 'analysis', 'recording', 'ros', 'commands', 'testing']
NO_RCLPY = {'core', 'fmu', 'analysis', 'recording', 'commands'}
LIBRARY = ['core', 'fmu', 'analysis', 'recording', 'ros']
COMMANDS = PACKAGE / 'commands'
# What a subcommand's module may import of commands/: the shared options, nothing else.
SHARED_COMMAND_MODULES = {'options'}


def imported_modules(path):
    """Yield (module name, at module level) for every import statement of a file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    top_level = {id(node) for node in tree.body}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, id(node) in top_level
        elif isinstance(node, ast.ImportFrom) and node.module:
            if node.module == 'valve_sim' or node.module.count('.') == 1 and (
                node.module.split('.')[0] == 'valve_sim'
            ):  # from valve_sim(.wing) import module
                for alias in node.names:
                    yield f'{node.module}.{alias.name}', id(node) in top_level
            else:
                yield node.module, id(node) in top_level


def modules():
    return sorted(PACKAGE.rglob('*.py'))


def wing_of(path):
    relative = path.relative_to(PACKAGE)
    return relative.parts[0] if len(relative.parts) > 1 else None


def test_every_module_lives_in_a_wing():
    loose = [p.name for p in PACKAGE.glob('*.py') if p.name != '__init__.py']
    assert loose == [], f'modules outside the wings: {loose}'
    assert sorted(
        p.name for p in PACKAGE.iterdir() if p.is_dir() and p.name != '__pycache__'
    ) == sorted(WINGS)


@pytest.mark.parametrize('wing', WINGS)
def test_each_wing_says_what_lives_there_and_what_it_may_import(wing):
    docstring = ast.get_docstring(ast.parse((PACKAGE / wing / '__init__.py').read_text()))
    assert docstring and 'May import' in docstring


@pytest.mark.parametrize('path', modules(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_go_only_downward(path):
    wing = wing_of(path)
    if wing is None:
        return
    level = WINGS.index(wing)
    problems = []
    for module, top_level in imported_modules(path):
        parts = module.split('.')
        if parts[0] == 'valve_sim' and len(parts) > 1 and parts[1] in WINGS:
            if WINGS.index(parts[1]) > level:
                problems.append(f'{module} (wing {parts[1]} is above {wing})')
        if parts[0] == 'rclpy' and wing in NO_RCLPY:
            problems.append(f'{module} ({wing} must not import rclpy: ros/ drives nodes)')
    assert problems == [], f'{path.relative_to(PACKAGE)} imports upward: {problems}'


@pytest.mark.parametrize(
    'path',
    sorted(p for p in COMMANDS.glob('*.py') if p.name not in ('__init__.py', 'cli.py')),
    ids=lambda p: p.name,
)
def test_a_subcommand_imports_no_other_subcommand(path):
    """Commands import only the library and commands/options.py (library code is not here)."""
    siblings = sorted(
        module
        for module, _ in imported_modules(path)
        if module.startswith('valve_sim.commands.')
        and module.split('.')[2] not in SHARED_COMMAND_MODULES
    )
    assert siblings == [], f'commands/{path.name} imports other commands: {siblings}'


@pytest.mark.parametrize('wing', LIBRARY)
def test_the_library_never_imports_the_commands(wing):
    found = sorted(
        f'{path.relative_to(PACKAGE)}: {module}'
        for path in (PACKAGE / wing).rglob('*.py')
        for module, _ in imported_modules(path)
        if module == 'valve_sim.commands' or module.startswith('valve_sim.commands.')
    )
    assert found == [], f'the library imports commands/: {found}'


def test_the_check_sees_an_upward_import(tmp_path):
    bad = tmp_path / 'bad.py'
    bad.write_text('def f():\n    from valve_sim.ros import valve_node\n')
    assert ('valve_sim.ros.valve_node', False) in list(imported_modules(bad))


def test_the_check_sees_a_sibling_command_in_each_form(tmp_path):
    bad = tmp_path / 'bad.py'
    bad.write_text(
        'from valve_sim.commands import simulate\n'
        'from valve_sim.commands.analyse import run\n'
        'import valve_sim.commands.study\n'
    )
    assert {module for module, _ in imported_modules(bad)} == {
        'valve_sim.commands.simulate', 'valve_sim.commands.analyse', 'valve_sim.commands.study'
    }
