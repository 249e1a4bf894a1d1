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
Every file valve_sim reads, read defensively: each reader against every hostile input.

The readers, through the functions their users call: fault schedules, parameter files,
bag folders' metadata.yaml, a study's results.jsonl (--resume), calibrate's target
measures. The inputs (hostile_inputs): FIFOs, directories, /dev/zero, missing and
sparse 2 GiB files, alias bombs, deep nesting, numbers no float holds, bytes that are
not text, and seeded random damage of each reader's own valid file. Each must end in
well under the time limit with the document or one line naming the file, never a
traceback, a hang or a memory blow-up.
"""

import json
from pathlib import Path

from hostile_inputs import FILES, JSON_TEXTS, make_file, mutations, YAML_TEXTS
import pytest
from valve_sim.analysis.design.robust_yield import check_candidate_row
from valve_sim.analysis.scenarios.bench_scenario import load_scenario
from valve_sim.analysis.studies.results import read_results
from valve_sim.commands.cli import main
from valve_sim.core.errors import CalibrationError, InputFileError, ParameterError, StudyError
from valve_sim.core.fault_schedule import load_schedule
from valve_sim.core.parameters import config_path, load_parameters
from valve_sim.recording.rosbag2_metadata import bag_files


pytestmark = pytest.mark.timeout(120)

REFUSALS = (InputFileError, ParameterError, StudyError, CalibrationError)
STUDY = 'fingerprint'
METADATA = """rosbag2_bagfile_information:
  version: 9
  storage_identifier: mcap
  relative_file_paths:
    - run_0.mcap
  files:
    - path: run_0.mcap
"""


def read_schedule(path):
    return load_schedule(path)


def read_parameters(path):
    return load_parameters(path, with_injection=True)


def read_metadata(path):
    """Read path as the metadata.yaml of a bag folder (the folder holds it by that name)."""
    folder = path.parent / f'{path.name}.bag'
    folder.mkdir()
    if path.exists() or path.is_symlink():
        path.rename(folder / 'metadata.yaml')
    (folder / 'run_0.mcap').touch()
    return bag_files(folder)


def read_study_results(path, check=None):
    """Read path as results.jsonl: a valid header, then path's content as the rows."""
    results = path.parent / f'{path.name}.jsonl'
    header = json.dumps({'study': STUDY, 'cases': 1}) + '\n'
    if path.is_file() and not path.is_symlink() and path.stat().st_size < 1024**2:
        results.write_bytes(header.encode() + path.read_bytes() + b'\n')
    elif path.exists() or path.is_symlink():  # a FIFO, a device, a sparse file: as it is
        path.rename(results)
    return read_results(results, STUDY, check)


def read_optimise_results(path):
    """Read path as one of optimise's results files (--resume): candidate rows."""
    return read_study_results(path, check_candidate_row)


YAML_READERS = {
    'fault schedule': read_schedule,
    'parameter file': read_parameters,
    'bag metadata': read_metadata,
    'scenario': load_scenario,
}
JSON_READERS = {'study results': read_study_results, 'optimise results': read_optimise_results}
RUNNER_ROW = {
    'index': 0,
    'measures': {'P_o_percent': 0.1, 'P_1_percent': 3.1, 'T_1_ms': 6.8, 'r_d': 0.8,
                 'T_d_ms': 25.0, 'T_s_ms': None},
    'reasons': {'T_s_ms': 'no settling'},
    'error': None,
}
CANDIDATE_ROW = {  # as robust_yield.evaluate_candidate writes it (two valves kept)
    'index': 3, 'label': 'candidate 3', 'design': {'damping_orifice_diameter': 1.02e-3},
    'samples': 2, 'error': None, 'preset_pressure': 7e6,
    'nominal': {**RUNNER_ROW, 'decay_rate': 12.5, 'pass': True},
    'passed': 1, 'ci95': [0.0126, 0.987], 'failures': {'r_d<=0.85': 1, 'run failed': 0},
    'percentiles': {'r_d': {'defined': 2, 'undefined': 0, 'p50': 0.8}}, 'yield': 0.5,
    'pass': '10', 'sample_rows': [{**RUNNER_ROW, 'index': i, 'pass': i == 0} for i in (0, 1)],
}
VALID = {
    'fault schedule': config_path('fault_schedule_example.yaml').read_bytes(),
    'parameter file': config_path('reference.yaml').read_bytes(),
    'bag metadata': METADATA.encode(),
    'scenario': (Path(__file__).resolve().parents[2] / 'scenarios'
                 / 'stuck_main_valve.yaml').read_bytes(),
    'study results': json.dumps(RUNNER_ROW).encode(),
    'optimise results': json.dumps(CANDIDATE_ROW).encode(),
}


def refused(read, path):
    """Return the message of the refusal of path by read; fail if it reads it or crashes."""
    with pytest.raises(REFUSALS) as error:
        read(path)
    message = str(error.value)
    assert '\n' not in message and len(message) < 1000, message
    return message


@pytest.mark.parametrize('content', list(FILES) + list(YAML_TEXTS))
@pytest.mark.parametrize('reader', list(YAML_READERS))
def test_every_yaml_reader_refuses_every_hostile_file_in_one_line(tmp_path, reader, content):
    path = tmp_path / 'input.yaml'
    make_file(path, FILES.get(content) or YAML_TEXTS.get(content))
    if (reader, content) == ('bag metadata', 'a missing file'):  # a folder never closed
        assert read_metadata(path) == [tmp_path / 'input.yaml.bag' / 'run_0.mcap']
        return
    message = refused(YAML_READERS[reader], path)
    assert 'input.yaml' in message, message


@pytest.mark.parametrize('content', list(FILES) + list(JSON_TEXTS))
@pytest.mark.parametrize('reader', list(JSON_READERS))
def test_every_json_reader_refuses_every_hostile_file_in_one_line(tmp_path, reader, content):
    path = tmp_path / 'input'
    make_file(path, FILES.get(content) or JSON_TEXTS.get(content))
    if content == 'a missing file':  # no results file: nothing to resume, no error
        assert JSON_READERS[reader](path) == {}
        return
    message = refused(JSON_READERS[reader], path)
    assert 'input' in message, message


@pytest.mark.parametrize('reader', list(YAML_READERS) + list(JSON_READERS))
def test_random_damage_of_a_valid_file_is_read_or_refused_in_one_line(tmp_path, reader):
    """Fuzz: 150 seeded mutations of the reader's own valid file; nothing else may escape."""
    read = {**YAML_READERS, **JSON_READERS}[reader]
    assert read_valid(tmp_path, reader, VALID[reader]) is not None
    for number, damaged in enumerate(mutations(VALID[reader], 150, seed=25)):
        path = tmp_path / f'fuzz{number}'
        path.write_bytes(damaged)
        try:
            read(path)
        except REFUSALS as error:
            assert '\n' not in str(error), error


def read_valid(tmp_path, reader, data):
    path = tmp_path / 'valid'
    path.write_bytes(data)
    return {**YAML_READERS, **JSON_READERS}[reader](path)


def test_schema_errors_name_the_file_and_the_key(tmp_path):
    """A metadata.yaml naming its files with numbers; results rows with a wrong key."""
    path = tmp_path / 'input.yaml'
    path.write_text(METADATA.replace('- run_0.mcap\n  files', '- 7\n  files'))
    assert 'relative_file_paths' in refused(read_metadata, path)
    changes = (('index', 'zero'), ('measures', {'P_o_percent': 1}), ('error', 5),
               ('reasons', []), ('cracking_pressure', 'high'))
    rows_refused_naming_the_key(tmp_path, read_study_results, RUNNER_ROW, changes)


def rows_refused_naming_the_key(tmp_path, read, row, changes):
    """Each (key, value) of changes set in row: read refuses it, naming the key and line 2."""
    for key, value in changes:
        path = tmp_path / f'row_{key}'
        path.write_text(json.dumps({**row, key: value}))
        message = refused(read, path)
        assert f"'{key}'" in message and 'line 2' in message, message


def test_a_resumed_row_of_the_study_envelope_or_optimise_is_read_and_checked(tmp_path):
    """The envelope's decay rate is a measure too; optimise's rows have their own keys."""
    path = tmp_path / 'envelope'
    row = {**RUNNER_ROW, 'measures': {**RUNNER_ROW['measures'], 'envelope_decay_per_s': 5.0}}
    path.write_text(json.dumps(row))
    assert read_study_results(path)[0] == row
    path = tmp_path / 'candidate'
    path.write_text(json.dumps(CANDIDATE_ROW))
    assert read_optimise_results(path)[3] == CANDIDATE_ROW
    changes = (('design', {'d_c': 'wide'}), ('ci95', [0.1]), ('samples', -1),
               ('nominal', {**RUNNER_ROW, 'measures': {}}), ('pass', 1))
    rows_refused_naming_the_key(tmp_path, read_optimise_results, CANDIDATE_ROW, changes)


def test_a_nan_measure_in_a_resumed_study_is_refused(tmp_path):
    """Refuse a NaN in results.jsonl: it made every percentile of summary.json NaN."""
    path = tmp_path / 'row'
    path.write_text(VALID['study results'].decode().replace('0.1', 'NaN'))
    assert 'NaN' in refused(read_study_results, path)


@pytest.mark.parametrize('content', ['random bytes', 'objects nested 1000 levels', 'NaN', '1e400',
                                     'a 5000-digit integer', 'a string, not an object'])
def test_calibrate_refuses_hostile_target_measures_in_one_line(tmp_path, capsys, content):
    path = tmp_path / 'target.json'
    make_file(path, JSON_TEXTS[content])
    code = main(['calibrate', '--target-measures', str(path), '--fit', 'd_c',
                 '--out', str(tmp_path / 'out')])
    error = capsys.readouterr().err
    assert code == 1 and error.count('\n') == 1 and str(path) in error, error


@pytest.mark.parametrize('option', ['--params', '--faults'])
@pytest.mark.parametrize('content', ['/dev/zero', 'a FIFO', 'a sparse 2 GiB file',
                                     'a list alias bomb', 'a dict alias bomb'])
def test_simulate_refuses_a_hostile_params_or_faults_file(tmp_path, capsys, option, content):
    path = tmp_path / 'input.yaml'
    make_file(path, FILES.get(content) or YAML_TEXTS.get(content))
    code = main(['simulate', option, str(path), '--end-time', '0.3'])
    error = capsys.readouterr().err
    assert code == 1 and error.count('\n') == 1 and 'input.yaml' in error, error


def test_what_is_checked_is_what_is_applied(tmp_path):
    """A schedule read from the file opened first, whatever the path holds later."""
    from valve_sim.core.fault_schedule import open_schedule

    path = tmp_path / 'schedule.yaml'
    path.write_bytes(VALID['fault schedule'])
    stream = open_schedule(path)
    replacement = tmp_path / 'other.yaml'
    replacement.write_bytes(YAML_TEXTS['random bytes'])
    replacement.replace(path)
    assert load_schedule(path, stream) == load_schedule(
        config_path('fault_schedule_example.yaml')
    )


def test_the_limits_are_documented():
    """docs/valve_node.md states each kind of file's size limit and the schedule's events."""
    from valve_sim.core.input_files import KINDS, MAX_EVENTS, size_text

    docs = (Path(__file__).resolve().parents[2] / 'docs' / 'valve_node.md').read_text()
    for kind in KINDS:
        assert kind.name in docs, kind.name
        if kind.max_bytes:
            assert size_text(kind.max_bytes) in docs, (kind.name, size_text(kind.max_bytes))
    assert f'{MAX_EVENTS:,}' in docs
