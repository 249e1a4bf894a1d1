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
The results file of a study: its fingerprint, rows read back for a resume, their check.

run_cases() (studies.runner) appends every finished row to a JSON-lines file, its
first line the study's fingerprint(); read_results() reads the rows of that very
study back (a resume), each checked by check_row() (the rows of evaluate_batch) or
a caller's own check; drop_torn_tail() cuts a row the process died writing.
"""

from dataclasses import asdict
import hashlib
import json
import os
from pathlib import Path

from valve_sim.analysis.steps.measures import ENVELOPE_DECAY, MEASURE_NAMES
from valve_sim.core.errors import InputFileError, StudyError
from valve_sim.core.input_documents import parse_json
from valve_sim.core.input_files import json_lines, shown, STUDY_RESULTS, STUDY_ROW


# The numbers a row may hold besides its measures (evaluate_batch, _measured).
NUMBER_KEYS = (
    'pilot_spring_preload',
    'cracking_pressure',
    'initial_supply_pressure',
    'initial_main_valve_displacement',
)


def fingerprint(cases):
    """
    Hash of everything that determines a study's results (cases in order).

    A case is a studies.cases.StudyCase (hashed as its fingerprint_fields(), the dict
    the study's cases were before they were a dataclass, so older results folders
    still resume) or a dict (the optimisation's candidates).
    """
    digest = hashlib.sha256()
    for case in cases:
        fields = case.fingerprint_fields() if hasattr(case, 'fingerprint_fields') else case
        plain = {
            key: asdict(value) if hasattr(value, '__dataclass_fields__') else value
            for key, value in fields.items()
        }
        digest.update(json.dumps(plain, sort_keys=True, default=list).encode())
    return digest.hexdigest()[:16]


def case_index(case):
    """Return a case's index: a StudyCase's attribute, or a candidate dict's key."""
    return case['index'] if isinstance(case, dict) else case.index


def read_results(path, study, check=None):
    """
    Rows on file for the study with this fingerprint: {index: row}.

    A missing file gives {}; a file of another study raises StudyError. Every row
    ends with a newline: a torn last line (the process died while writing it) is
    not a row, and drop_torn_tail() removes it before new rows are appended. The file
    is read once, within input_files' limits (STUDY_RESULTS, each line STUDY_ROW), and
    every row is checked by check (default check_row, the rows of evaluate_batch; the
    rows of another evaluate need their own): a damaged one is a StudyError naming its
    line.
    """
    check = check or check_row
    path = Path(path)
    if not os.path.lexists(path):
        return {}
    lines = json_lines(path, STUDY_RESULTS, STUDY_ROW)
    header = {}
    for number, text in lines:
        try:
            header = parse_json(text, STUDY_ROW, f'{path}, line {number},')
        except InputFileError:
            pass
        break
    if not isinstance(header, dict) or header.get('study') != study:
        raise StudyError(
            f'{path} holds results of a different study (other parameters, samples or '
            'seed); give another --out or run without --resume to start afresh'
        )
    rows = {}
    for number, text in lines:
        where = f'{path}, line {number}'
        try:
            row = parse_json(text, STUDY_ROW, where)
            check(row)
        except (InputFileError, ValueError) as error:
            raise StudyError(
                f'{where}: not a row of this study ({error}); delete that line to compute '
                'the run again, or run without --resume to start afresh'
            ) from None
        rows.setdefault(row['index'], row)
    return rows


def check_row(row):
    """Raise ValueError naming the key unless row is a results row as evaluate_batch makes it."""
    if not isinstance(row, dict):
        raise InputFileError(f'a row is a JSON object, got {shown(row)}')
    index = row.get('index')
    if isinstance(index, bool) or not isinstance(index, int) or index < 0:
        raise InputFileError(f"key 'index' must be an integer >= 0, got {shown(index)}")
    measures = row.get('measures')
    if not isinstance(measures, dict) or not set(MEASURE_NAMES) <= set(measures) <= set(
        MEASURE_NAMES + (ENVELOPE_DECAY,)
    ):
        raise InputFileError(
            f"key 'measures' must map {', '.join(MEASURE_NAMES)} (and {ENVELOPE_DECAY}, if "
            'asked) to numbers or null'
        )
    for name, value in measures.items():
        if value is not None and not is_number(value):
            raise InputFileError(
                f"key 'measures.{name}' must be a number or null, got {shown(value)}"
            )
    reasons = row.get('reasons')
    if not isinstance(reasons, dict) or not all(isinstance(r, str) for r in reasons.values()):
        raise InputFileError(f"key 'reasons' must map measure names to text, got {shown(reasons)}")
    if row.get('error') is not None and not isinstance(row['error'], str):
        raise InputFileError(f"key 'error' must be text or null, got {shown(row['error'])}")
    for key in NUMBER_KEYS:
        if key in row and not is_number(row[key]):
            raise InputFileError(f"key '{key}' must be a number, got {shown(row[key])}")
    waveforms = row.get('waveforms', {'time': []})
    if not isinstance(waveforms, dict) or not all(
        isinstance(trace, list) and all(map(is_number, trace)) for trace in waveforms.values()
    ):
        raise InputFileError("key 'waveforms' must map names to lists of numbers")


def is_number(value):
    """Return whether a value read from JSON is a number (an int or a float, not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def drop_torn_tail(path):
    """Cut a file after its last newline (a row that was being written when it died)."""
    with open(path, 'r+b') as stream:
        data = stream.read()
        stream.truncate(data.rfind(b'\n') + 1)
