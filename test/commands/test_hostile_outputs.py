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
Outputs go only where the user said, and only into regular files (issue 43, section 1).

- a device or FIFO the user named (--junit, fmu --out, through a link or not) is
  written in place or refused in one line, never replaced by a regular file; one
  inside an output folder is refused;
- links inside an output folder are not followed out of it: the nodes' logs,
  optimise's DIR/params and DIR/evaluations;
- a scenario's name from its file is made one safe path component before it names
  the default output folder; JUnit XML stays well-formed whatever the text.
Devices are never the real /dev ones: FIFOs, links and (as root) device nodes made in
temporary folders.
"""

import os
from pathlib import Path
import stat
import sys
import threading
from types import SimpleNamespace
import xml.etree.ElementTree as ElementTree
import zipfile

import pytest
from valve_sim.analysis.scenarios.report import junit_document, write_junit
from valve_sim.commands.cli import main
from valve_sim.core import output_files
from valve_sim.core.errors import OutputFileError
from valve_sim.ros.node_processes import NodeProcesses


pytestmark = pytest.mark.timeout(120)

SCENARIO = SimpleNamespace(name='s', path=Path('s.yaml'))
UP = '../' * 3  # out of the working folder and two above


def fifo_behind_link(folder):
    """Make a FIFO in folder and a link to it: (fifo, link)."""
    fifo, link = folder / 'pipe', folder / 'link.xml'
    os.mkfifo(fifo)
    link.symlink_to(fifo)
    return fifo, link


def read_fifo(fifo, received):
    """Start a thread that reads fifo to its end into received['data']."""
    def reader():
        with open(fifo, 'rb') as stream:
            received['data'] = stream.read()
    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    return thread


def test_junit_into_a_linked_fifo_with_no_reader_is_refused_and_the_fifo_kept(
    tmp_path, monkeypatch
):
    monkeypatch.setattr(output_files, 'FIFO_WAIT', 0.1, raising=False)
    fifo, link = fifo_behind_link(tmp_path)
    with pytest.raises(OutputFileError, match='FIFO with no reader'):
        write_junit(junit_document(SCENARIO, [], error='boom'), tmp_path, link)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
    assert sorted(path.name for path in tmp_path.iterdir()) == ['link.xml', 'pipe']


def test_junit_into_a_linked_fifo_with_a_reader_is_written_through_it(tmp_path):
    fifo, link = fifo_behind_link(tmp_path)
    received = {}
    thread = read_fifo(fifo, received)
    write_junit(junit_document(SCENARIO, [], error='boom'), tmp_path, link)
    thread.join(30)
    assert ElementTree.fromstring(received['data']).find('.//error').get('message') == 'boom'
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)


@pytest.mark.skipif(os.geteuid() != 0, reason='device nodes need root')
def test_a_named_full_device_is_one_line_and_stays_a_device(tmp_path):
    """A copy of /dev/full (1, 7) made here: --junit /dev/full must not replace it."""
    device = tmp_path / 'full'
    try:
        os.mknod(device, stat.S_IFCHR | 0o666, os.makedev(1, 7))
    except OSError as error:
        pytest.skip(f'no device node here: {error}')
    with pytest.raises(OutputFileError) as refused:
        output_files.write_text(device, 'x' * 100_000, explicit=True)
    assert '\n' not in str(refused.value)
    assert stat.S_ISCHR(os.lstat(device).st_mode)


def test_a_fifo_or_folder_inside_an_output_folder_is_refused(tmp_path):
    os.mkfifo(tmp_path / 'report.txt')
    with pytest.raises(OutputFileError, match='is a FIFO, not a regular file'):
        output_files.write_text(tmp_path / 'report.txt', 'x')
    with pytest.raises(OutputFileError, match='is a FIFO'):
        output_files.fresh_file(tmp_path / 'report.txt')
    (tmp_path / 'folder').mkdir()
    with pytest.raises(IsADirectoryError) as refused:  # caught as before, and a ValveSimError
        with output_files.replacing(tmp_path / 'folder') as stream:
            stream.write('x')
    assert isinstance(refused.value, OutputFileError)


def test_fmu_out_through_a_link_to_a_fifo_is_one_line_and_the_fifo_kept(
    tmp_path, capsys, monkeypatch
):
    pytest.importorskip('pythonfmu')
    monkeypatch.setattr(output_files, 'FIFO_WAIT', 0.1, raising=False)
    import valve_sim.fmu.builder as builder

    built = tmp_path / 'built.fmu'
    with zipfile.ZipFile(built, 'w') as fmu:  # as pythonfmu packs one: a linux64 binary
        fmu.writestr('binaries/linux64/ReliefValve.so', b'')

    class Builder:  # the FMU's content does not matter here, only where it goes

        @staticmethod
        def build_FMU(*args, **options):
            return built

    monkeypatch.setattr('pythonfmu.FmuBuilder', Builder)
    fifo = tmp_path / 'pipe'
    os.mkfifo(fifo)
    (tmp_path / 'valve.fmu').symlink_to(fifo)
    assert main(['fmu', '--out', str(tmp_path / 'valve.fmu')]) == 1
    error = capsys.readouterr().err.strip()
    assert 'FIFO with no reader' in error and '\n' not in error
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and builder.build


def test_node_logs_are_not_written_through_a_planted_link(tmp_path):
    victim = tmp_path / 'victim.txt'
    victim.write_text('precious')
    out = tmp_path / 'out'
    out.mkdir()
    (out / 'valve_node.log').symlink_to(victim)
    processes = NodeProcesses(out, {'valve_node': [sys.executable, '-c', 'print("started")']})
    processes.processes['valve_node'].wait(60)
    assert victim.read_text() == 'precious'
    assert not (out / 'valve_node.log').is_symlink()
    assert (out / 'valve_node.log').read_text() == 'started\n'


def test_optimise_does_not_follow_links_at_params_and_evaluations(tmp_path, monkeypatch, capsys):
    """The command's output folder, made before the search (which is stopped here)."""
    out, victim = tmp_path / 'out', tmp_path / 'elsewhere'
    out.mkdir()
    for name in ('params', 'evaluations'):
        (victim / name).mkdir(parents=True)
        (out / name).symlink_to(victim / name)

    def no_search(*args, **options):
        raise OutputFileError('stopped before the search')

    monkeypatch.setattr('valve_sim.commands.optimise.open_backend', no_search)
    assert main(['optimise', '--design', 'd_c=±5%', '--minimise', 'P_1_percent',
                 '--tolerance', 'd_c=±5um', '--out', str(out), '--population', '4',
                 '--generations', '1', '--samples', '2']) == 1
    assert 'stopped before the search' in capsys.readouterr().err
    for name in ('params', 'evaluations'):
        assert (out / name).is_dir() and not (out / name).is_symlink()
        assert (victim / name).is_dir()


@pytest.mark.parametrize('name, expected', [
    (UP + 'tmp/x/y', '_.._.._tmp_x_y'), ('a\0b', 'a_b'), ('..', 'unnamed'),
    ('step\x1b[31m', 'step_31m'), ('Ventilprüfung 2', 'Ventilprüfung_2'),
])
def test_names_from_files_become_one_safe_path_component(name, expected):
    assert output_files.safe_name(name) == expected


@pytest.mark.parametrize('name', [UP + 'tmp/x/y', 'nul\\0byte'])  # YAML: a NUL
def test_a_scenario_name_names_a_folder_inside_the_working_folder(
    tmp_path, monkeypatch, capsys, name
):
    """The default output folder of `scenario run` (the run itself is stopped here)."""
    scenario = tmp_path / 'work' / 'bad.yaml'
    scenario.parent.mkdir()
    scenario.write_text(f'scenario: "{name}"\nduration: 0.5\n'
                        'inputs: {inlet_flow: 5 L/min}\nexpect: [{no_alarm: {}}]\n')

    def no_run(*args, **options):
        raise OutputFileError('stopped before the run')

    monkeypatch.setattr('valve_sim.ros.scenario_runner.run_and_report', no_run)
    monkeypatch.chdir(scenario.parent)
    assert main(['scenario', 'run', str(scenario)]) == 1
    assert 'stopped before the run' in capsys.readouterr().err
    made = [path for path in tmp_path.rglob('*') if path.is_dir() and path != scenario.parent]
    assert len(made) == 1 and made[0].parent == scenario.parent, made


def test_junit_is_well_formed_whatever_the_text():
    scenario = SimpleNamespace(name='bell\x07 esc\x1b[31m nul\0', path=Path('p\udc80.yaml'))
    document = junit_document(scenario, [], 1.0, error='diverged \x01\x02 \ufffe here')
    suite = ElementTree.fromstring(document).find('testsuite')
    assert suite.get('name') == 'bell\\x07 esc\\x1b[31m nul\\x00'
    assert suite.find('.//error').get('message') == 'diverged \\x01\\x02 \\ufffe here'


def test_a_recording_named_as_a_fifo_is_refused_in_one_line(tmp_path):
    """A FIFO as `simulate --mcap`: the MCAP writer seeks (it hung, or died: Illegal seek)."""
    from valve_sim.recording.bag import BagWriter

    fifo = tmp_path / 'live.mcap'
    os.mkfifo(fifo)
    with pytest.raises(OutputFileError, match='is a FIFO, not a regular file'):
        BagWriter(fifo)
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)
