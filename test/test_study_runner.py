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
The study runner on a real Dask cluster: same results, worker death, resume.

The cluster is a scheduler and two worker processes started here as `dask
scheduler` / `dask worker` subprocesses, as a user starts them on other machines.
"""

import argparse
import json
import os
import signal
import subprocess
import sys
import time

import pytest
from valve_sim.analysis.paper import REFERENCE_SCENARIO
from valve_sim.analysis.study_runner import (
    DaskBackend,
    evaluate_batch,
    PoolBackend,
    run_cases,
    SerialBackend,
)
from valve_sim.commands.study import run_all
from valve_sim.commands.study_backend import open_backend
from valve_sim.core.errors import StudyError
from valve_sim.core.parameters import scaled


DASK = [sys.executable, '-m', 'dask']
START_TIMEOUT = 180.0  # [s] generous: the machine is shared


def wait_for(condition, timeout, what):
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f'timed out after {timeout} s waiting for {what}'
        time.sleep(0.05)


def start_worker(scheduler_file, name):
    return subprocess.Popen(
        [*DASK, 'worker', '--scheduler-file', str(scheduler_file), '--nthreads', '1',
         '--no-nanny', '--no-dashboard', '--name', name, '--host', '127.0.0.1'],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )


def stop(process):
    if process.poll() is None:
        os.killpg(process.pid, signal.SIGTERM)
        try:
            process.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


@pytest.fixture(scope='module')
def cluster(tmp_path_factory):
    """Yield (address, scheduler file) of a scheduler with two single-thread workers."""
    from distributed import Client

    scheduler_file = tmp_path_factory.mktemp('dask') / 'scheduler.json'
    processes = [
        subprocess.Popen(
            [*DASK, 'scheduler', '--scheduler-file', str(scheduler_file), '--port', '0',
             '--no-dashboard', '--host', '127.0.0.1'],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
        )
    ]
    try:
        wait_for(scheduler_file.exists, START_TIMEOUT, 'the scheduler file')
        processes += [start_worker(scheduler_file, f'worker-{i}') for i in (1, 2)]
        address = json.loads(scheduler_file.read_text())['address']
        with Client(address, timeout='60s') as client:
            wait_for(lambda: len(client.nthreads()) == 2, START_TIMEOUT, 'two workers')
        yield address, scheduler_file
    finally:
        for process in reversed(processes):
            stop(process)


def valve_cases(reference, count):
    """Count variations of the paper's test: d_c from -4 % in steps of 0.5 %."""
    return [
        {
            'index': index,
            'params': scaled(reference, {'d_c': -4.0 + 0.5 * index}),
            'preset_pressure': None,
            'scenario': REFERENCE_SCENARIO,
            'step_size': 1e-5,
            'record': [],
        }
        for index in range(count)
    ]


def file_indices(path):
    return [json.loads(line)['index'] for line in path.read_text().splitlines()[1:]]


def test_a_two_worker_cluster_gives_exactly_the_local_results(cluster, reference, tmp_path):
    cases = valve_cases(reference, 6)
    local, _ = run_cases(cases, tmp_path / 'local.jsonl', SerialBackend(), progress_stream=None)
    backend = DaskBackend(cluster[0])
    try:
        assert backend.workers == 2
        distributed, computed = run_cases(
            cases, tmp_path / 'dask.jsonl', backend, batch_size=1, progress_stream=None
        )
    finally:
        backend.close()
    assert computed == 6
    assert distributed == local
    assert all(row['error'] is None and row['measures']['T_1_ms'] for row in local.values())


class KillingBackend:
    """The real DaskBackend; after the first finished batch it kills a busy worker."""

    def __init__(self, backend, victim, victim_address):
        self.backend, self.victim, self.victim_address = backend, victim, victim_address
        self.workers = backend.workers
        self.killed_while_processing = None

    def run(self, evaluate, batches):
        for number, rows in enumerate(self.backend.run(evaluate, batches)):
            if number == 0:
                client = self.backend.client

                def busy():
                    return client.processing(workers=[self.victim_address]).get(
                        self.victim_address
                    )
                wait_for(busy, 60.0, 'the victim worker to hold a task')
                self.killed_while_processing = list(busy())
                os.killpg(self.victim.pid, signal.SIGKILL)
            yield rows


def test_a_worker_killed_mid_study_loses_no_run_and_duplicates_none(
    cluster, reference, tmp_path
):
    address, scheduler_file = cluster
    victim = start_worker(scheduler_file, 'victim')
    backend = DaskBackend(address)
    try:
        client = backend.client
        wait_for(lambda: len(client.nthreads()) == 3, START_TIMEOUT, 'the third worker')
        victim_address = next(
            a for a, info in client.scheduler_info()['workers'].items() if info['name'] == 'victim'
        )
        killing = KillingBackend(backend, victim, victim_address)
        cases = valve_cases(reference, 24)
        rows, computed = run_cases(
            cases, tmp_path / 'results.jsonl', killing, batch_size=1, progress_stream=None
        )
        assert killing.killed_while_processing
        wait_for(lambda: victim_address not in client.nthreads(), 60.0, 'the scheduler to notice')
    finally:
        backend.close()
        stop(victim)
    assert computed == 24
    assert sorted(file_indices(tmp_path / 'results.jsonl')) == list(range(24))
    local, _ = run_cases(cases, tmp_path / 'local.jsonl', SerialBackend(), progress_stream=None)
    assert rows == local


class InterruptedBackend(SerialBackend):
    """Serial batches, with Ctrl-C after `batches` of them."""

    def __init__(self, batches):
        self.batches = batches

    def run(self, evaluate, batches):
        for number, rows in enumerate(super().run(evaluate, batches)):
            if number == self.batches:
                raise KeyboardInterrupt
            yield rows


class DuplicatingBackend(SerialBackend):
    """Delivers every batch twice, as a recomputed task after a lost worker may."""

    def run(self, evaluate, batches):
        for rows in super().run(evaluate, batches):
            yield rows
            yield rows


def test_resume_after_an_interruption_computes_only_the_missing_runs(reference, tmp_path):
    cases = valve_cases(reference, 8)
    path = tmp_path / 'results.jsonl'
    evaluated = []

    def counting(batch):
        evaluated.extend(case['index'] for case in batch)
        return evaluate_batch(batch)

    with pytest.raises(KeyboardInterrupt):
        run_cases(cases, path, InterruptedBackend(2), batch_size=2, evaluate=counting,
                  progress_stream=None)
    saved = path.read_text()
    assert len(saved.splitlines()) == 1 + 4
    with open(path, 'a') as stream:
        stream.write('{"index": 4, "meas')  # the process died while writing a row
    evaluated.clear()
    rows, computed = run_cases(cases, path, DuplicatingBackend(), resume=True, batch_size=2,
                               evaluate=counting, progress_stream=None)
    assert sorted(evaluated) == [4, 5, 6, 7] and computed == 4
    assert path.read_text().startswith(saved)
    assert sorted(file_indices(path)) == list(range(8))
    fresh, _ = run_cases(cases, tmp_path / 'fresh.jsonl', SerialBackend(), progress_stream=None)
    assert rows == fresh
    evaluated.clear()
    again, computed = run_cases(cases, path, SerialBackend(), resume=True, evaluate=counting,
                                progress_stream=None)
    assert evaluated == [] and computed == 0 and again == rows
    other = valve_cases(reference, 9)
    with pytest.raises(StudyError, match='different study'):
        run_cases(other, path, SerialBackend(), resume=True, progress_stream=None)


def test_the_papers_study_on_a_cluster_equals_the_pool_and_resumes(
    cluster, reference, tmp_path
):
    pool = run_all(
        reference, 1e-5, PoolBackend(2), tmp_path / 'pool.jsonl', progress_stream=None
    )
    backend = DaskBackend(cluster[0])
    try:
        on_cluster = run_all(
            reference, 1e-5, backend, tmp_path / 'out' / 'results.jsonl', progress_stream=None
        )
    finally:
        backend.close()
    assert len(on_cluster) == 26
    for label, (measures, poppet) in on_cluster.items():
        assert measures == pool[label][0]
        assert (poppet is None) == (pool[label][1] is None)
    resumed = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'study', '--out', str(tmp_path / 'out'),
         '--scheduler', cluster[0], '--resume'],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr
    assert 'resuming: 26 of 26 runs' in resumed.stderr
    assert (tmp_path / 'out' / 'figure08_pilot_poppet.png').exists()


def test_without_dask_the_study_runs_on_a_process_pool_and_the_others_say_what_to_install(
    monkeypatch, capsys
):
    monkeypatch.setitem(sys.modules, 'distributed', None)
    args = argparse.Namespace(scheduler=None, workers=2, batch_size=None)
    assert isinstance(open_backend(args, 'study', pool_fallback=True), PoolBackend)
    assert 'local process pool' in capsys.readouterr().err
    with pytest.raises(StudyError, match=r"pip install 'dask\[distributed\]'"):
        open_backend(args, 'tolerance')
