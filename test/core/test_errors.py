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

"""One error model: one root, each error defined and imported once, bugs keep their traceback."""

import ast
import errno
import importlib
import os
from pathlib import Path
import signal

import pytest
from valve_sim.commands import cli
from valve_sim.commands.options import ctrl_c_stops
from valve_sim.core import errors
from valve_sim.core.errors import OutputFileError, USER_ERRORS, ValveSimError
from valve_sim.core.output_files import append_to, write_text

ROOT = Path(__file__).resolve().parents[2]
SOURCES = sorted(
    path for folder in ('valve_sim', 'test', 'bench') for path in (ROOT / folder).rglob('*.py')
)
BUILTIN_BASES = {  # what callers catch them by, besides the root
    'ParameterError': ValueError,
    'SectionError': ValueError,
    'InputFileError': ValueError,
    'OutputFileError': OSError,
    'IntegrationError': RuntimeError,
    'SteadyStateError': RuntimeError,
    'IncompleteRunError': RuntimeError,
    'StudyError': RuntimeError,
}


def module_name(path):
    return '.'.join(path.relative_to(ROOT).with_suffix('').parts)


def defined_errors():
    """Return {class name: module} of every public exception class valve_sim defines."""
    found = {}
    for path in (ROOT / 'valve_sim').rglob('*.py'):
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.ClassDef) and not node.name.startswith('_') and (
                node.name.endswith(('Error', 'Exception'))
            ):
                assert node.name not in found, f'{node.name} is defined twice'
                found[node.name] = module_name(path)
    return found


def test_every_error_has_the_one_root_and_keeps_its_builtin_base():
    defined = defined_errors()
    assert defined['ValveSimError'] == 'valve_sim.core.errors'
    for name, module in defined.items():
        error = getattr(importlib.import_module(module), name)
        assert issubclass(error, ValveSimError), name
    for name, base in BUILTIN_BASES.items():
        assert issubclass(getattr(errors, name), base), name
    assert issubclass(errors.CalibrationError, errors.ParameterError)
    assert issubclass(errors.ProfileError, errors.InputFileError)
    assert issubclass(errors.OverpressureError, errors.IntegrationError)


def test_each_error_is_imported_from_the_module_that_defines_it():
    """No error is reachable under two import paths: project code imports it from its home."""
    defined = defined_errors()
    elsewhere = []
    for path in SOURCES:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module:
                elsewhere += [
                    f'{path.relative_to(ROOT)}:{node.lineno}: {alias.name} from {node.module}'
                    for alias in node.names
                    if defined.get(alias.name, node.module) != node.module
                ]
    assert not elsewhere, '\n'.join(elsewhere)


def failing_run(monkeypatch, error):
    """Make `valve-sim operating-point` raise error; return the CLI's exit code."""
    module = importlib.import_module('valve_sim.commands.operating_point')

    def run(args):
        raise error

    monkeypatch.setattr(module, 'run', run)
    return cli.main(['operating-point'])


@pytest.mark.parametrize('error', [
    OSError(errno.EIO, 'Input/output error'),
    OSError(errno.EBADF, 'Bad file descriptor', 'x'),
    ConnectionRefusedError(errno.ECONNREFUSED, 'Connection refused'),
])
def test_an_unexpected_os_error_is_not_swallowed_as_a_user_error(monkeypatch, error):
    """A bug's OSError is no user error: it reaches the caller, whose traceback shows it."""
    assert not isinstance(error, USER_ERRORS)
    with pytest.raises(type(error)):
        failing_run(monkeypatch, error)


@pytest.mark.parametrize('error, line', [
    (FileNotFoundError(errno.ENOENT, 'No such file or directory', 'in.yaml'),
     'in.yaml: No such file or directory'),
    (PermissionError(errno.EACCES, 'Permission denied', 'out'), 'out: Permission denied'),
    (errors.ParameterError('damping_orifice_diameter must be > 0'),
     'damping_orifice_diameter must be > 0'),
    (OutputFileError(errno.ENOSPC, 'No space left on device', 'out/run.csv'),
     'out/run.csv: No space left on device'),
])
def test_a_user_error_is_one_line(monkeypatch, capsys, error, line):
    assert failing_run(monkeypatch, error) == 1
    assert capsys.readouterr().err == f'valve-sim operating-point: error: {line}\n'


def test_a_file_that_cannot_be_written_is_a_user_error_naming_it(tmp_path):
    missing = tmp_path / 'no_folder' / 'report.json'
    with pytest.raises(OutputFileError) as refused:
        write_text(missing, '{}\n')
    assert isinstance(refused.value, ValveSimError) and isinstance(refused.value, OSError)
    assert refused.value.errno == errno.ENOENT and refused.value.filename == str(missing)
    link = tmp_path / 'results.jsonl'
    os.symlink(tmp_path / 'elsewhere', link)
    with pytest.raises(OutputFileError) as refused:
        append_to(link)
    assert refused.value.errno == errno.ELOOP and refused.value.filename == str(link)


def test_library_code_leaves_ctrl_c_to_its_caller():
    """Only the commands and the nodes catch KeyboardInterrupt; the library takes a callback."""
    catching = []
    for path in (ROOT / 'valve_sim').rglob('*.py'):
        if path.parent.name in ('commands', 'ros'):
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ExceptHandler) and node.type is not None and (
                'KeyboardInterrupt' in ast.unparse(node.type)
            ):
                catching.append(f'{path.relative_to(ROOT)}:{node.lineno}')
    assert not catching, catching


def test_the_first_ctrl_c_asks_the_library_to_stop_the_second_interrupts():
    before = signal.getsignal(signal.SIGINT)
    with ctrl_c_stops() as should_stop:
        assert not should_stop()
        os.kill(os.getpid(), signal.SIGINT)
        assert should_stop()  # asked, not raised: the computation ends with what it has
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)  # Python runs the handler right after it
    assert signal.getsignal(signal.SIGINT) is before
