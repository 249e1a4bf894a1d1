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

A case is a dict:
  index            int, unique within its study (the bookkeeping key)
  params           complete model parameter dict (SI), as sampled (validated here:
                   a sample outside a parameter's limits is that case's error)
  preset_pressure  [Pa] the valve is set to crack at this pressure before its test
                   (the pilot spring preload y_0 re-solved, as a technician turns the
                   screw); None keeps params' preload (frozen preload)
  scenario         core.simulation.Scenario
  step_size        [s] RK4 step
  record           state names whose waveforms the row keeps (usually empty)
evaluate_batch(cases) -> rows is the one work unit: a row holds index, the preload
used, the cracking pressure, the initial p_s and x, the six measures, their reasons,
and error (a message when the valve could not be set or the run failed; then the
measures are None).

run_cases() submits batches to a backend (DaskBackend, PoolBackend, SerialBackend)
and appends every finished row to a JSON-lines results file as it arrives (first
line: the study's fingerprint), so an interrupted study resumes with only the
missing indices. A row whose index is already on file is dropped, so a batch that
Dask recomputes after a worker died is never recorded twice. Dask is imported only
by DaskBackend.
"""

from dataclasses import asdict
import hashlib
import json
import math
import os
from pathlib import Path
import sys
import time

from valve_sim.analysis.measures import (
    ENVELOPE_DECAY,
    envelope_decay_rate,
    MEASURE_NAMES,
    step_measures,
)
from valve_sim.core.batch import simulate_batch
from valve_sim.core.errors import InputFileError, MODEL_ERRORS, StudyError
from valve_sim.core.input_files import json_lines, parse_json, shown, STUDY_RESULTS, STUDY_ROW
from valve_sim.core.output_files import append_to, finite, write_text
from valve_sim.core.parameters import validate
from valve_sim.core.steady_state import cracking_pressure, preset_preload


RECORD_INTERVAL = 1e-4  # [s] sample interval of the waveforms the measures are taken from
TASKS_PER_WORKER = 8  # batches per worker: small enough to balance, large enough to amortise
MAX_BATCH = 64
LOOPBACK = '127.0.0.1'  # where every part of a local cluster listens


# The numbers a row may hold besides its measures (evaluate_batch, _measured).
NUMBER_KEYS = (
    'pilot_spring_preload',
    'cracking_pressure',
    'initial_supply_pressure',
    'initial_main_valve_displacement',
)


def evaluate_case(case):
    """Set the valve to its preset, run the step test and measure it; return its row."""
    return evaluate_batch([case])[0]


def evaluate_batch(cases):
    """
    Rows of a batch of cases (the work unit a backend runs), in the order of cases.

    Each valve is set to its preset first. Cases that share a scenario and step
    size then run together through core.batch.simulate_batch: several valves
    per kernel call, each bit-identical to a run of its own, the stable steady
    state before the step held instead of integrated (docs/speed.md). A row does
    not depend on which cases share its batch.
    """
    rows, groups = {}, {}
    for case in cases:
        row = {'index': case['index']}
        try:
            params = validate(case['params'])
            if case.get('preset_pressure') is None:
                cracking = cracking_pressure(params)
            else:
                preload, cracking = preset_preload(params, case['preset_pressure'])
                params = {**params, 'pilot_spring_preload': preload}
            row['pilot_spring_preload'] = params['pilot_spring_preload']
            row['cracking_pressure'] = cracking
        except MODEL_ERRORS as error:
            rows[case['index']] = _failed(row, error)
            continue
        key = (case['scenario'], case['step_size'])
        groups.setdefault(key, []).append((case, row, params))
    for (scenario, step_size), members in groups.items():
        outcomes = simulate_batch(
            [params for _, _, params in members], scenario, step_size, RECORD_INTERVAL
        )
        for (case, row, _), outcome in zip(members, outcomes):
            rows[case['index']] = (
                _measured(case, row, outcome.waveforms)
                if outcome.success
                else _failed(row, outcome.message)
            )
    return [rows[case['index']] for case in cases]


def _failed(row, reason):
    return {**row, 'measures': dict.fromkeys(MEASURE_NAMES), 'reasons': {}, 'error': str(reason)}


def _measured(case, row, waveforms):
    """
    Complete the row of a run: initial state, the six measures and reasons, waveforms.

    A case with 'envelope' set gets the envelope's decay rate too (ENVELOPE_DECAY).
    """
    scenario = case['scenario']
    row['initial_supply_pressure'] = float(waveforms['supply_pressure'][0])
    row['initial_main_valve_displacement'] = float(waveforms['main_valve_displacement'][0])
    measures = step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        scenario.step_time,
        1 if scenario.final_flow >= scenario.initial_flow else -1,
    ).as_dict()
    row.update(
        measures={
            name: None if measures[name] is None else float(measures[name])
            for name in MEASURE_NAMES
        },
        reasons=measures['reasons'],
        error=None,
    )
    if case.get('envelope'):  # T_s's continuous companion, for the study (docs/measures.md)
        decay, reason = envelope_decay_rate(
            waveforms.time,
            waveforms['supply_pressure'],
            waveforms['main_valve_displacement'],
            scenario.step_time,
        )
        row['measures'][ENVELOPE_DECAY] = decay
        if reason:
            row['reasons'][ENVELOPE_DECAY] = reason
    if case.get('record'):
        row['waveforms'] = {
            'time': waveforms.time.tolist(),
            **{name: waveforms[name].tolist() for name in case['record']},
        }
    return row


def fingerprint(cases):
    """Hash of everything that determines a study's results (cases in order)."""
    digest = hashlib.sha256()
    for case in cases:
        plain = {
            key: asdict(value) if hasattr(value, '__dataclass_fields__') else value
            for key, value in case.items()
        }
        digest.update(json.dumps(plain, sort_keys=True, default=list).encode())
    return digest.hexdigest()[:16]


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
        raise ValueError(f'a row is a JSON object, got {shown(row)}')
    index = row.get('index')
    if isinstance(index, bool) or not isinstance(index, int) or index < 0:
        raise ValueError(f"key 'index' must be an integer >= 0, got {shown(index)}")
    measures = row.get('measures')
    if not isinstance(measures, dict) or not set(MEASURE_NAMES) <= set(measures) <= set(
        MEASURE_NAMES + (ENVELOPE_DECAY,)
    ):
        raise ValueError(
            f"key 'measures' must map {', '.join(MEASURE_NAMES)} (and {ENVELOPE_DECAY}, if "
            'asked) to numbers or null'
        )
    for name, value in measures.items():
        if value is not None and not is_number(value):
            raise ValueError(f"key 'measures.{name}' must be a number or null, got {shown(value)}")
    reasons = row.get('reasons')
    if not isinstance(reasons, dict) or not all(isinstance(r, str) for r in reasons.values()):
        raise ValueError(f"key 'reasons' must map measure names to text, got {shown(reasons)}")
    if row.get('error') is not None and not isinstance(row['error'], str):
        raise ValueError(f"key 'error' must be text or null, got {shown(row['error'])}")
    for key in NUMBER_KEYS:
        if key in row and not is_number(row[key]):
            raise ValueError(f"key '{key}' must be a number, got {shown(row[key])}")
    waveforms = row.get('waveforms', {'time': []})
    if not isinstance(waveforms, dict) or not all(
        isinstance(trace, list) and all(map(is_number, trace)) for trace in waveforms.values()
    ):
        raise ValueError("key 'waveforms' must map names to lists of numbers")


def is_number(value):
    """Return whether a value read from JSON is a number (an int or a float, not a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def drop_torn_tail(path):
    """Cut a file after its last newline (a row that was being written when it died)."""
    with open(path, 'r+b') as stream:
        data = stream.read()
        stream.truncate(data.rfind(b'\n') + 1)


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
    indices = [case['index'] for case in cases]
    if len(set(indices)) != len(indices):
        raise ValueError('case indices must be unique')
    study = fingerprint(cases)
    results_path = Path(results_path)
    if results_path.is_symlink():
        raise StudyError(
            f'{results_path} is a symbolic link: valve-sim does not write a results file '
            'through a link; remove it or give another --out'
        )
    rows = read_results(results_path, study, check) if resume else {}
    rows = {index: row for index, row in rows.items() if index in set(indices)}
    missing = [case for case in cases if case['index'] not in rows]
    if resume and rows:
        _say(
            progress_stream,
            f'{label}: resuming: {len(rows)} of {len(cases)} runs on file in {results_path}',
        )
    if resume and results_path.exists():
        drop_torn_tail(results_path)
    else:
        results_path.parent.mkdir(parents=True, exist_ok=True)
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


class SerialBackend:
    """Batches one after another in this process (tests, debugging)."""

    workers = 1

    def run(self, evaluate, batches):
        for batch in batches:
            yield evaluate(batch)

    def close(self):
        pass


class PoolBackend:
    """A local process pool: the paper's study when dask is not installed."""

    def __init__(self, workers):
        self.workers = max(1, workers)

    def run(self, evaluate, batches):
        from concurrent.futures import as_completed, ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=self.workers) as pool:
            futures = [pool.submit(evaluate, batch) for batch in batches]
            try:
                for future in as_completed(futures):
                    yield future.result()
            finally:
                for future in futures:
                    future.cancel()

    def close(self):
        pass


class DaskBackend:
    """
    Batches as tasks on a dask.distributed cluster.

    address: a scheduler (tcp://HOST:PORT) of an existing cluster, connected at once;
    or None for a LocalCluster of `workers` single-threaded processes on this
    machine (default: one per core), started when the first batch is submitted, so
    that a resumed study with nothing missing starts none. A task whose worker dies
    is rescheduled by Dask; `retries` re-runs a task that raised.

    The local cluster listens on the loopback interface only (scheduler, workers,
    nannies, and the scheduler's HTTP routes on a free port): its pages show the
    workers' details, and nothing of it is for the network. dashboard: also serve
    Dask's dashboard there, at HOST:PORT ('127.0.0.1:0': this machine, a free port;
    '0.0.0.0:8787' only when the network is meant to see it); its address is
    dashboard_link once started.
    """

    def __init__(self, address=None, workers=None, retries=3, dashboard=None):
        self.retries, self.dashboard = retries, dashboard
        self.cluster = self._client = None
        if address:
            from distributed import Client

            try:
                self._client = Client(address, timeout='30s')
            except (OSError, ValueError, TimeoutError) as error:
                raise StudyError(
                    f'cannot reach the Dask scheduler {address!r} (expected tcp://HOST:PORT): '
                    f'{error}'
                ) from None
            self.workers = max(1, sum(self._client.nthreads().values()))
        else:
            self.workers = max(1, workers or os.cpu_count() or 1)

    @property
    def started(self):
        """Whether a client exists: connected to the scheduler, or a local cluster started."""
        return self._client is not None

    @property
    def client(self):
        """Return the Dask client; the first use starts the local cluster."""
        return self.start()._client

    def start(self):
        """Start the local cluster now (else it starts with the first batch); return self."""
        if self._client is None:
            import logging

            from distributed import Client, LocalCluster

            self.cluster = LocalCluster(
                n_workers=self.workers,
                threads_per_worker=1,
                processes=True,
                host=LOOPBACK,
                dashboard_address=self.dashboard,
                # without a dashboard the scheduler still serves health and metrics routes
                scheduler_kwargs={'dashboard_address': self.dashboard or f'{LOOPBACK}:0'},
                silence_logs=logging.ERROR,
            )
            self._client = Client(self.cluster)
        return self

    @property
    def dashboard_link(self):
        """Return the address of Dask's dashboard, or None without one (or before start)."""
        if self._client is None or (self.cluster is not None and not self.dashboard):
            return None
        return self._client.dashboard_link

    def run(self, evaluate, batches):
        if not batches:
            return
        from distributed import as_completed

        futures = [
            self.client.submit(evaluate, batch, retries=self.retries, pure=False)
            for batch in batches
        ]
        try:
            for future in as_completed(futures):
                try:
                    yield future.result()
                except Exception as error:  # noqa: B902  (KilledWorker, a worker's bug)
                    first, last = future_cases(batches, futures, future)
                    raise StudyError(
                        f'the batch of cases {first}-{last} failed on the cluster: '
                        f'{type(error).__name__}: {error}'
                    ) from error
        finally:
            self.client.cancel(futures)

    def close(self):
        if self._client is not None:
            self._client.close()
        if self.cluster is not None:
            self.cluster.close()


def future_cases(batches, futures, future):
    """First and last case index of the batch a future ran."""
    batch = batches[futures.index(future)]
    return batch[0]['index'], batch[-1]['index']
