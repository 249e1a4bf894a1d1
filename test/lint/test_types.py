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
The library's public surface is typed: mypy --strict passes on it, every verb annotated.

The surface: what `valve_sim` and `valve_sim.testing` export and the code of
docs/python.md (extracted into a module, checked as a user's script would be: calling
an unannotated verb is an error under --strict). The modules behind the verbs are
followed silently (their bodies are not checked, their signatures are used).
"""

import importlib
import inspect
from pathlib import Path
import subprocess
import sys

import pytest

ROOT = Path(__file__).resolve().parents[2]
SURFACE = ['valve_sim/__init__.py', 'valve_sim/core/valve.py', 'valve_sim/testing/__init__.py']


def unannotated(function):
    """Return the names of function's parameters (and 'return') that carry no annotation."""
    signature = inspect.signature(function)
    missing = [
        name for name, parameter in signature.parameters.items()
        if parameter.annotation is inspect.Parameter.empty and name not in ('self', 'cls')
        and parameter.kind not in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD)
    ]
    if signature.return_annotation is inspect.Signature.empty:
        missing.append('return')
    return missing


def members(value):
    """Yield (name, function) of an exported function, or a class's public methods."""
    if inspect.isfunction(value):
        yield value.__name__, value
    elif inspect.isclass(value) and value.__module__.startswith('valve_sim'):
        for name, member in vars(value).items():
            if isinstance(member, property):
                member = member.fget
            if inspect.isfunction(member) and (name == '__init__' or not name.startswith('_')):
                yield f'{value.__name__}.{name}', member


@pytest.mark.parametrize('package', ['valve_sim', 'valve_sim.testing'])
def test_every_exported_verb_is_annotated(package):
    module = importlib.import_module(package)
    problems = {
        name: unannotated(function)
        for exported in module.__all__
        for name, function in members(getattr(module, exported))
        if unannotated(function)
    }
    assert problems == {}, f'exported without annotations: {problems}'


def test_mypy_strict_passes_on_the_public_surface(tmp_path):
    pytest.importorskip('mypy')
    sys.path.insert(0, str(ROOT / 'test' / 'library'))
    try:
        from test_python_doc import code_blocks, PAGE
    finally:
        sys.path.pop(0)
    example = tmp_path / 'python_doc_example.py'
    example.write_text('\n'.join(code_blocks(PAGE.read_text())))
    command = [
        sys.executable, '-m', 'mypy', '--strict', '--follow-imports=silent',
        '--no-error-summary', '--cache-dir', str(tmp_path / 'mypy_cache'),
        '--python-version', '3.10', *SURFACE, str(example),
    ]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
