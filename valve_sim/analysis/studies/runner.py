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
The study runner: many step tests in batches, on Dask or a local process pool.

A case is a studies.cases.StudyCase: its index (the bookkeeping key), the valve's
parameters, the preset it is set to, the flow step, the RK4 step and what to record.
evaluate_batch(cases) -> rows is the one work unit: a row holds index, the preload
used, the cracking pressure, the initial p_s and x, the six measures, their reasons,
and error (a message when the valve could not be set or the run failed; then the
measures are None).

run_cases() submits batches to a backend (backend: DaskBackend, PoolBackend,
SerialBackend) and appends every finished row to a JSON-lines results file as it
arrives (results: first line the study's fingerprint), so an interrupted study
resumes with only the missing indices. A row whose index is already on file is
dropped, so a batch that Dask recomputes after a worker died is never recorded twice.
"""

import json
import math
from pathlib import Path
import sys
import time

from valve_sim.analysis.steps.measures import (
    ENVELOPE_DECAY,
    envelope_decay_rate,
    MEASURE_NAMES,
    step_measures,
)
from valve_sim.analysis.studies.results import (
    case_index,
    drop_torn_tail,
    fingerprint,
    read_results,
)
from valve_sim.core.batch import simulate_batch
from valve_sim.core.errors import MODEL_ERRORS, ParameterError, StudyError
from valve_sim.core.output_files import append_to, finite, make_folder, write_text
from valve_sim.core.parameters import validate
from valve_sim.core.steady_state import cracking_pressure, preset_preload


RECORD_INTERVAL = 1e-4  # [s] sample interval of the waveforms the measures are taken from
TASKS_PER_WORKER = 8  # batches per worker: small enough to balance, large enough to amortise
MAX_BATCH = 64


def evaluate_case(case):
    """Set the valve to its preset, run the step test and measure it; return its row."""
    return evaluate_batch([case])[0]


def evaluate_batch(cases):
    """
    Rows of a batch of cases (the work unit a backend runs), in the order of cases.

    Each valve is set to its preset first. Cases that share a flow_step and step
    size then run together through core.batch.simulate_batch: several valves
    per kernel call, each bit-identical to a run of its own, the stable steady
    state before the step held instead of integrated (docs/speed.md). A row does
    not depend on which cases share its batch.
    """
    rows, groups = {}, {}
    for case in cases:
        row = {'index': case.index}
        try:
            params = validate(case.params)
            if case.preset_pressure is None:
                cracking = cracking_pressure(params)
            else:
                preload, cracking = preset_preload(params, case.preset_pressure)
                params = {**params, 'pilot_spring_preload': preload}
            row['pilot_spring_preload'] = params['pilot_spring_preload']
            row['cracking_pressure'] = cracking
        except MODEL_ERRORS as error:
            rows[case.index] = _failed(row, error)
            continue
        key = (case.flow_step, case.step_size)
        groups.setdefault(key, []).append((case, row, params))
    for (flow_step, step_size), members in groups.items():
        outcomes = simulate_batch(
            [params for _, _, params in members], flow_step, step_size, RECORD_INTERVAL
        )
        for (case, row, _), outcome in zip(members, outcomes):
            rows[case.index] = (
                _measured(case, row, outcome.waveforms)
                if outcome.success
                else _failed(row, outcome.message)
            )
    return [rows[case.index] for case in cases]


def _failed(row, reason):
    return {**row, 'measures': dict.fromkeys(MEASURE_NAMES), 'reasons': {}, 'error': str(reason)}


def _measured(case, row, waveforms):
    """
    Complete the row of a run: initial state, the six measures and reasons, waveforms.

    A case with envelope set gets the envelope's decay rate too (ENVELOPE_DECAY).
    """
    flow_step = case.flow_step
    row['initial_supply_pressure'] = float(waveforms['supply_pressure'][0])
    row['initial_main_valve_displacement'] = float(waveforms['main_valve_displacement'][0])
    measures = step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        flow_step.step_time,
        1 if flow_step.final_flow >= flow_step.initial_flow else -1,
    ).as_dict()
    row.update(
        measures={
            name: None if measures[name] is None else float(measures[name])
            for name in MEASURE_NAMES
        },
        reasons=measures['reasons'],
        error=None,
    )
    if case.envelope:  # T_s's continuous companion, for the study (docs/measures.md)
        decay, reason = envelope_decay_rate(
            waveforms.time,
            waveforms['supply_pressure'],
            waveforms['main_valve_displacement'],
            flow_step.step_time,
        )
        row['measures'][ENVELOPE_DECAY] = decay
        if reason:
            row['reasons'][ENVELOPE_DECAY] = reason
    if case.record:
        row['waveforms'] = {
            'time': waveforms.time.tolist(),
            **{name: waveforms[name].tolist() for name in case.record},
        }
    return row


def compile_lanes():
    """
    Compile (or load from numba's cache) the lanes kernel every batch runs: run.py's install.

    One reference valve through a short flow step, as evaluate_batch runs it. Done once
    there, not at the first batch of a study, tolerance run or optimisation, where each
    Dask worker of a fresh install would compile it at once. Not in core.precompile: that
    runs in every colcon build, which needs only valve_node's kernels.
    """
    from valve_sim.core.parameters import load_parameters
    from valve_sim.core.flow_step import FlowStep

    simulate_batch([load_parameters().params], FlowStep(step_time=0.01, end_time=0.02),
                   record_interval=RECORD_INTERVAL)


def batches_of(cases, batch_size):
    """Split cases into consecutive batches of at most batch_size."""
    return [cases[i:i + batch_size] for i in range(0, len(cases), batch_size)]


def default_batch_size(count, workers):
    """About TASKS_PER_WORKER batches per worker, at most MAX_BATCH cases each."""
    return max(1, min(MAX_BATCH, math.ceil(count / (max(1, workers) * TASKS_PER_WORKER))))


class Progress:
    """Progress and ETA on stderr, at most one line every `interval` seconds."""

    def __init__(self, label, total, done, stream=sys.stderr, interval=2.0, unit='runs'):
        self.label, self.total, self.resumed = label, total, done
        self.done, self.stream, self.interval, self.unit = done, stream, interval, unit
        self.start = self.last = time.monotonic()

    def skip(self, count):
        """Count items found done on file: they do not count in the rate."""
        self.done += count
        self.resumed += count

    def advance(self, count):
        self.done += count
        now = time.monotonic()
        if now - self.last < self.interval and self.done < self.total:
            return
        self.last = now
        rate = (self.done - self.resumed) / max(now - self.start, 1e-9)
        left = (self.total - self.done) / rate if rate > 0 else float('inf')
        pace = f'{rate:.1f} {self.unit}/s' if rate >= 1.0 else f'{60.0 * rate:.1f} {self.unit}/min'
        _say(
            self.stream,
            f'{self.label}: {self.done}/{self.total} {self.unit} '
            f'({100.0 * self.done / self.total:.0f} %), {pace}, '
            f'elapsed {_duration(now - self.start)}, '
            f'ETA {_duration(left)}',
        )


def _say(stream, text):
    """Print a line to stream (None: stay silent)."""
    if stream is not None:
        print(text, file=stream, flush=True)


def _duration(seconds):
    if not math.isfinite(seconds):
        return '?'
    minutes, seconds = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f'{hours}h{minutes:02d}m' if hours else f'{minutes}m{seconds:02d}s'


def run_cases(
    cases,
    results_path,
    backend,
    resume=False,
    batch_size=None,
    evaluate=evaluate_batch,
    label='study',
    progress_stream=sys.stderr,
    progress=None,
    check=None,
):
    """
    Evaluate every case once, streaming rows to results_path; return (rows, computed).

    rows: {index: row} for all cases; computed: how many were evaluated in this call
    (the rest came from the file with resume=True). Without resume an existing file
    is replaced. An interruption (Ctrl-C, a failed batch) leaves every finished row
    on file and raises; resume=True then evaluates only the missing indices.
    Progress goes to progress_stream (None: silent), or to progress, a Progress that
    spans more than this call (the rows on file are skipped in it). check: the row
    check of evaluate's rows for a resume (read_results; default check_row).
    """
    indices = [case_index(case) for case in cases]
    if len(set(indices)) != len(indices):
        raise ParameterError('case indices must be unique')
    study = fingerprint(cases)
    results_path = Path(results_path)
    if results_path.is_symlink():
        raise StudyError(
            f'{results_path} is a symbolic link: valve-sim does not write a results file '
            'through a link; remove it or give another --out'
        )
    rows = read_results(results_path, study, check) if resume else {}
    rows = {index: row for index, row in rows.items() if index in set(indices)}
    missing = [case for case in cases if case_index(case) not in rows]
    if resume and rows:
        _say(
            progress_stream,
            f'{label}: resuming: {len(rows)} of {len(cases)} runs on file in {results_path}',
        )
    if resume and results_path.exists():
        drop_torn_tail(results_path)
    else:
        make_folder(results_path.parent)
        write_text(results_path, json.dumps({'study': study, 'cases': len(cases)}) + '\n')
    if progress is None:
        progress = Progress(label, len(cases), len(rows), progress_stream)
    else:
        progress.skip(len(rows))
    size = batch_size or default_batch_size(len(missing), backend.workers)
    computed = 0
    with append_to(results_path) as stream:
        try:
            for batch_rows in backend.run(evaluate, batches_of(missing, size)):
                fresh = [row for row in batch_rows if row['index'] not in rows]
                for row in fresh:
                    rows[row['index']] = row
                    stream.write(json.dumps(finite(row)) + '\n')
                stream.flush()
                computed += len(fresh)
                progress.advance(len(fresh))
        except BaseException:
            _say(
                progress_stream,
                f'{label}: stopped; {len(rows)} of {len(cases)} runs are saved in '
                f'{results_path}: --resume completes the rest',
            )
            raise
    lost = set(indices) - set(rows)
    if lost:
        raise StudyError(f'{len(lost)} runs produced no result; rerun with --resume')
    return rows, computed
