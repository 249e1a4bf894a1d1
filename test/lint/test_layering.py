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
never another subcommand (cli, the entry point, finds them by name). No circle of
imports anywhere, inside a wing too; inside the analysis wing each room
(sub-package) imports only the rooms below it (ANALYSIS_ROOMS), functions included.
Imports inside functions count for circles too.
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
ANALYSIS = PACKAGE / 'analysis'
# The analysis wing's rooms and top-level modules -> what else of the wing each may import
# (as each room's __init__ says): paper at the bottom, then steps, then the figures and a
# recording's steps, then the rooms that build on them.
TOP = {'paper', 'plotting', 'characteristic', 'recorded_steps'}
ANALYSIS_ROOMS = {
    'paper': set(),
    'steps': {'paper'},
    'characteristic': set(),
    'plotting': {'steps', 'characteristic'},
    'recorded_steps': {'steps', 'paper', 'plotting'},
    'studies': {'paper', 'steps', 'plotting'},
    'scenarios': {'paper', 'steps', 'plotting'},
    'calibration': {'paper', 'steps', 'plotting', 'recorded_steps', 'studies'},
    'design': {'paper', 'steps', 'plotting', 'studies'},
}


def is_module(name):
    """Whether a dotted name is a module or package of valve_sim."""
    path = PACKAGE.parent.joinpath(*name.split('.'))
    return name.startswith('valve_sim') and (path.with_suffix('.py').is_file() or path.is_dir())


def imported_modules(path):
    """Yield (module name, at module level) for every import statement of a file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    top_level = {id(node) for node in tree.body}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, id(node) in top_level
        elif isinstance(node, ast.ImportFrom) and node.module:
            submodules = [f'{node.module}.{alias.name}' for alias in node.names]
            if node.module.split('.')[0] == 'valve_sim' and all(map(is_module, submodules)):
                yield from ((name, id(node) in top_level) for name in submodules)
            else:  # from valve_sim(.wing.room) import module, or names of a module
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


def module_name(path):
    relative = path.relative_to(PACKAGE.parent).with_suffix('')
    parts = relative.parts[:-1] if relative.name == '__init__' else relative.parts
    return '.'.join(parts)


def import_graph():
    """Return {module: {the valve_sim modules it imports}} for every module (functions' too)."""
    return {
        module_name(path): {
            module for module, _ in imported_modules(path)
            if module.startswith('valve_sim.') and is_module(module)
        }
        for path in modules()
    }


def circles(graph):
    """Return the circles of a graph {node: {nodes}}: one list per circle found (DFS)."""
    found, state = [], {}

    def visit(node, trail):
        state[node] = 'open'
        for following in sorted(graph.get(node, ())):
            if state.get(following) == 'open':
                found.append(trail[trail.index(following):] + [following])
            elif following not in state:
                visit(following, trail + [following])
        state[node] = 'done'

    for node in sorted(graph):
        if node not in state:
            visit(node, [node])
    return found


def test_no_circle_of_imports_anywhere_in_the_package():
    """
    Imports form no circle, across wings or inside one (or one room).

    Imports inside functions count too: a deferred import keeps a module light to load
    (numba, scipy at first use), it does not license two modules that need each other.
    """
    assert circles(import_graph()) == []


def test_the_check_sees_a_circle():
    graph = {'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}
    assert circles(graph) == [['a', 'b', 'c', 'a']]
    assert circles({'a': {'b'}, 'b': set()}) == []


def analysis_part(module):
    """Return the room or top-level module of the analysis wing a module name is in."""
    parts = module.split('.')
    return parts[2] if parts[:2] == ['valve_sim', 'analysis'] and len(parts) > 2 else None


def test_every_room_of_the_analysis_wing_has_its_rule_and_says_it():
    rooms = {p.name for p in ANALYSIS.iterdir() if (p / '__init__.py').is_file()}
    top = {p.stem for p in ANALYSIS.glob('*.py') if p.stem != '__init__'}
    assert top == TOP
    assert rooms | top == set(ANALYSIS_ROOMS)
    for room in rooms:
        docstring = ast.get_docstring(ast.parse((ANALYSIS / room / '__init__.py').read_text()))
        assert docstring and 'Lives here' in docstring and 'May import' in docstring, room
    assert [p for p in PACKAGE.glob('*/*/__init__.py') if p.parent.parent != ANALYSIS] == []


@pytest.mark.parametrize(
    'path', sorted(ANALYSIS.rglob('*.py')), ids=lambda p: str(p.relative_to(ANALYSIS))
)
def test_each_room_imports_only_the_rooms_below_it(path):
    """A room's modules (functions too) import of the wing only their room and its rule's."""
    own = analysis_part(module_name(path))
    if own is None:
        return
    allowed = ANALYSIS_ROOMS[own] | {own}
    outside = sorted(
        module for module, _ in imported_modules(path)
        if analysis_part(module) not in (None, *allowed)
    )
    assert outside == [], f'analysis/{own} may import only {sorted(allowed)}: {outside}'


def test_the_rooms_rules_form_no_circle():
    assert circles({room: set(below) for room, below in ANALYSIS_ROOMS.items()}) == []
