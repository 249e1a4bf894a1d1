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
The study runner on a real Dask cluster, and the tolerance and sensitivity studies.

The cluster is a scheduler and two worker processes started here as `dask
scheduler` / `dask worker` subprocesses, as a user starts them on other machines.
"""

import csv
from dataclasses import replace
import io
import json
import math
import os
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.analysis.studies.backend import (
    DaskBackend, open_backend, PoolBackend, SerialBackend,
)
from valve_sim.analysis.studies.cases import run_all, StudyCase
from valve_sim.analysis.studies.runner import evaluate_batch, Progress, run_cases
from valve_sim.analysis.studies.sensitivity import sobol_design, sobol_indices
from valve_sim.analysis.studies.tolerances import (
    Distribution,
    parse_limits,
    parse_variations,
    summarise,
)
from valve_sim.core.errors import ParameterError, StudyError
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


def scheduler_address(scheduler_file):
    """Return the address in a Dask scheduler file, or None while it is missing or partial."""
    try:
        return json.loads(scheduler_file.read_text())['address']
    except (FileNotFoundError, ValueError, KeyError):
        return None


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
        # The scheduler creates its file before it writes it: wait until it parses.
        wait_for(lambda: scheduler_address(scheduler_file), START_TIMEOUT, 'the scheduler file')
        processes += [start_worker(scheduler_file, f'worker-{i}') for i in (1, 2)]
        address = scheduler_address(scheduler_file)
        with Client(address, timeout='60s') as client:
            wait_for(lambda: len(client.nthreads()) == 2, START_TIMEOUT, 'two workers')
        yield address, scheduler_file
    finally:
        for process in reversed(processes):
            stop(process)


def valve_cases(reference, count):
    """Count variations of the paper's test: d_c from -4 % in steps of 0.5 %."""
    return [
        StudyCase(index, scaled(reference, {'d_c': -4.0 + 0.5 * index}), None,
                  REFERENCE_FLOW_STEP, 1e-5)
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
        evaluated.extend(case.index for case in batch)
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


def test_a_resumed_study_with_nothing_missing_starts_no_local_cluster(reference, tmp_path):
    cases = valve_cases(reference, 2)
    path = tmp_path / 'results.jsonl'
    done, _ = run_cases(cases, path, SerialBackend(), progress_stream=None)
    backend = DaskBackend(workers=2)  # a local cluster, started on the first batch
    try:
        rows, computed = run_cases(cases, path, backend, resume=True, progress_stream=None)
        assert not backend.started and backend.cluster is None
    finally:
        backend.close()
    assert computed == 0 and rows == done


def test_progress_shows_the_rate_and_an_eta():
    stream = io.StringIO()
    progress = Progress('tolerance', 10, 2, stream, interval=0.0)  # 2 runs resumed
    progress.advance(3)
    assert re.fullmatch(
        r'tolerance: 5/10 runs \(50 %\), [\d.]+ runs/s, elapsed 0m00s, ETA \d+m\d\ds\n',
        stream.getvalue(),
    )


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
    for label, result in on_cluster.items():
        assert result['measures'] == pool[label]['measures']
        assert result['case'] == pool[label]['case']
        assert (result['poppet'] is None) == (pool[label]['poppet'] is None)
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
    assert isinstance(open_backend('study', workers=2, pool_fallback=True), PoolBackend)
    assert 'local process pool' in capsys.readouterr().err
    with pytest.raises(StudyError, match=r"pip install 'dask\[distributed\]'"):
        open_backend('tolerance', workers=2)


def test_a_bad_scheduler_address_is_one_clear_error():
    with pytest.raises(StudyError, match="cannot reach the Dask scheduler 'none'"):
        DaskBackend('none')


def valve_sim(*args):
    result = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', *args],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr
    return result


def test_tolerance_yield_and_percentiles_on_a_known_answer(cluster, reference, tmp_path):
    # P_1 falls monotonically with d_c. With d_c uniform on +-5 % and a 20-point Latin
    # hypercube (one sample in each 5 % stratum of d_c), a limit at P_1 of the d_c
    # quantile q = 0.25 is met by exactly the 15 valves above that quantile; the sample
    # median lies between P_1 at the quantiles 0.45 and 0.55, and p5 and p95 (numpy's
    # interpolation between the two most extreme samples) between P_1 at 0.9 and 1
    # and at 0 and 0.1.
    def p1_at(quantile):
        case = replace(valve_cases(reference, 1)[0],
                       params=scaled(reference, {'d_c': -5.0 + 10.0 * quantile}))
        return evaluate_batch([case])[0]['measures']['P_1_percent']

    limit = p1_at(0.25)
    out = tmp_path / 'tolerance'
    result = valve_sim(
        'tolerance', '--vary', 'd_c=±5%', '--samples', '20', '--seed', '7',
        '--limits', f'P_1_percent<={limit!r}', '--frozen-preload', '--out', str(out),
        '--scheduler', cluster[0],
    )
    with open(out / 'samples.csv') as stream:
        samples = list(csv.DictReader(stream))
    assert len(samples) == 20
    ordered = sorted(samples, key=lambda row: float(row['damping_orifice_diameter']))
    p1 = [float(row['P_1_percent']) for row in ordered]
    assert all(a > b for a, b in zip(p1, p1[1:])), 'the known answer needs P_1 monotonic'
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['protocol'] == 'frozen-preload'
    assert summary['distributions'][0]['distribution'] == 'uniform'
    assert summary['yield']['passed'] == 15 and summary['yield']['fraction'] == 0.75
    low, high = summary['yield']['ci95']
    assert low < 0.75 < high
    percentiles = summary['percentiles']['P_1_percent']
    assert p1_at(0.55) <= percentiles['p50'] <= p1_at(0.45)
    assert p1_at(1.0) <= percentiles['p5'] <= p1_at(0.9)
    assert p1_at(0.1) <= percentiles['p95'] <= p1_at(0.0)
    assert 'yield 15/20 = 75.0 %' in result.stdout
    assert (out / 'measures_cdf.png').exists()
    assert (out / 'measures_vs_damping_orifice_diameter.png').exists()


def test_the_summary_says_why_measures_are_undefined():
    def row(undefined=(), error=None):
        return {
            'error': error,
            'measures': {name: None if name in undefined else 1.0 for name in MEASURE_NAMES},
            'reasons': {} if error else dict.fromkeys(undefined, 'no second overshoot'),
        }

    failed = row(MEASURE_NAMES, 'no cracking point found: ...')
    rows = [row(), row(['r_d', 'T_d_ms']), row(['r_d', 'T_d_ms']), failed]
    summary = summarise(rows, parse_limits('P_1_percent<=2'))
    assert summary['yield']['passed'] == 3
    assert summary['percentiles']['r_d']['undefined_reasons'] == {
        'no second overshoot': 2, 'no cracking point found: ...': 1
    }
    assert summary['percentiles']['P_1_percent']['undefined_reasons'] == {
        'no cracking point found: ...': 1
    }
    assert 'undefined_reasons' not in summarise(rows[:1], [])['percentiles']['r_d']


def test_sensitivity_writes_indices_and_charts(cluster, tmp_path):
    out = tmp_path / 'sensitivity'
    result = valve_sim(
        'sensitivity', '--vary', 'd_c=±5%,k_p=±5%', '--samples', '4', '--out', str(out),
        '--scheduler', cluster[0],
    )
    assert '16 runs' in result.stderr and 'protocol held-preset' in result.stderr
    with open(out / 'indices.csv') as stream:
        rows = list(csv.DictReader(stream))
    assert [(row['measure'], row['symbol']) for row in rows[:2]] == [
        ('P_o_percent', 'd_c'), ('P_o_percent', 'k_p')
    ]
    assert len(rows) == 12
    assert len(list(out.glob('sobol_*.png'))) == 6


def ishigami_batch(cases):
    """Evaluate the Ishigami function (a = 7, b = 0.1) as a batch of runner rows."""
    return [
        {
            'index': case['index'],
            'measures': {
                'y': math.sin(case['x'][0]) + 7.0 * math.sin(case['x'][1]) ** 2
                + 0.1 * case['x'][2] ** 4 * math.sin(case['x'][0])
            },
        }
        for case in cases
    ]


def test_sobol_indices_of_the_ishigami_function_through_the_runner(tmp_path):
    a, b, pi = 7.0, 0.1, math.pi
    v1 = (1.0 + b * pi**4 / 5.0) ** 2 / 2.0
    v2 = a**2 / 8.0
    v13 = b**2 * pi**8 * (1.0 / 18.0 - 1.0 / 50.0)
    total = v1 + v2 + v13
    expected = {
        'S1': [v1 / total, v2 / total, 0.0],
        'ST': [(v1 + v13) / total, v2 / total, v13 / total],
    }
    distributions = [Distribution(f'x{i}', 'uniform', -pi, pi, '') for i in (1, 2, 3)]
    values = sobol_design(distributions, 1024, seed=1)
    cases = [{'index': i, 'x': [float(v) for v in row]} for i, row in enumerate(values)]
    rows, _ = run_cases(cases, tmp_path / 'ishigami.jsonl', SerialBackend(), batch_size=512,
                        evaluate=ishigami_batch, progress_stream=None)
    outputs = [rows[i]['measures']['y'] for i in range(len(values))]
    indices = sobol_indices(distributions, outputs, seed=1)
    for key in ('S1', 'ST'):
        for i in range(3):
            error = abs(indices[key][i] - expected[key][i])
            assert error <= max(0.03, 1.5 * indices[key + '_conf'][i]), (key, i, error)
            assert indices[key + '_conf'][i] < 0.1


def test_sobol_confidence_intervals_repeat_for_every_seed_zero_included():
    distributions = [Distribution(f'x{i}', 'uniform', 0.0, 1.0, '') for i in (1, 2)]
    values = sobol_design(distributions, 64, seed=0)
    outputs = values[:, 0] + 0.5 * values[:, 1] ** 2
    first, again = (sobol_indices(distributions, outputs, seed=0) for _ in range(2))
    for key in ('S1_conf', 'ST_conf'):
        assert np.array_equal(first[key], again[key]), key


@pytest.mark.parametrize(
    'text, kind, a, b',
    [
        ('d_c=±2%', 'uniform', 0.98e-3, 1.02e-3),
        ('damping_orifice_diameter=+-2%', 'uniform', 0.98e-3, 1.02e-3),
        ('delta_s=3e-6:7e-6', 'uniform', 3e-6, 7e-6),
        ('d_c=1.1e-3~N(1%)', 'normal', 1.1e-3, 1.1e-5),
        ('d_c=~N(2e-6)', 'normal', 1e-3, 2e-6),
    ],
)
def test_variation_forms(reference, text, kind, a, b):
    (distribution,) = parse_variations([text], reference)
    assert distribution.kind == kind
    assert distribution.a == pytest.approx(a) and distribution.b == pytest.approx(b)


@pytest.mark.parametrize(
    'text, message',
    [
        ('x_y=±2%', "unknown parameter 'x_y'"),
        ('d_c=2%', "'d_c=2%': SPEC must be"),
        ('d_c=5e-3:1e-3', 'LO < HI'),
        ('d_c=~N(0%)', 'sigma must be > 0'),
        ('d_c=±1%,d_c=±2%', 'varied twice: damping_orifice_diameter'),
        ('d_c=±1e300%', 'leave the limits of damping_orifice_diameter'),
        ('d_c=-1:1e-3', 'leave the limits of damping_orifice_diameter'),
        ('d_c=~N(1e300)', 'leave the limits of damping_orifice_diameter'),
        ('d_c=5~N(1%)', 'leave the limits of damping_orifice_diameter'),
    ],
)
def test_bad_variations_name_the_culprit(reference, text, message):
    with pytest.raises(ParameterError, match=re.escape(message)):
        parse_variations([text], reference)


def test_limits():
    (limit,) = parse_limits('P_1_percent<=4')
    assert limit.holds({'P_1_percent': 4.0}) and not limit.holds({'P_1_percent': None})
    with pytest.raises(ParameterError, match="limit 'P_9<=4'"):
        parse_limits('P_9<=4')


def test_the_dashboard_is_served_on_loopback_only_when_asked():
    """--dashboard: Dask's dashboard on this machine at a free port, its address known."""
    import psutil

    def listening(process):
        return {c.laddr for c in process.net_connections(kind='inet')
                if c.status == psutil.CONN_LISTEN}

    def port(address):
        return int(address.rsplit(':', 1)[1].split('/')[0])

    backend = DaskBackend(workers=1, dashboard='127.0.0.1:0')
    try:
        link = backend.start().dashboard_link
        nannies = list(backend.cluster.workers.values())
        ours = {port(link), port(backend.cluster.scheduler_address)}  # in this process
        ours |= {port(nanny.address) for nanny in nannies}
        here = {a for a in listening(psutil.Process()) if a.port in ours}
        workers = [psutil.Process(nanny.process.pid) for nanny in nannies]  # the cluster's
        there = set().union(*map(listening, workers))  # (other tests run clusters too)
    finally:
        backend.close()
    assert link.startswith('http://127.0.0.1:')
    assert {a.port for a in here} == ours and there
    assert {ip for ip, _ in here | there} == {'127.0.0.1'}
    assert DaskBackend(workers=1).dashboard_link is None  # none unless asked


def test_a_study_case_has_the_fingerprint_its_dict_had(reference):
    """Results folders written while cases were dicts still resume (their fingerprint holds)."""
    from valve_sim.analysis.studies.cases import runner_case, sample_cases
    from valve_sim.analysis.studies.results import fingerprint

    old_sample = {'index': 0, 'params': reference, 'preset_pressure': 7e6,
                  'scenario': REFERENCE_FLOW_STEP, 'step_size': 1e-5, 'record': []}
    assert fingerprint(sample_cases(reference, [], [[]], 7e6, 1e-5)) == fingerprint([old_sample])
    old_study = {**old_sample, 'params': scaled(reference, {'m_p': 10}),
                 'record': ['poppet_displacement'], 'envelope': True}
    new_study = runner_case(0, reference, {'m_p': 10}, 1e-5, 'held-preset', 7e6)
    assert fingerprint([new_study]) == fingerprint([old_study])
    assert fingerprint([replace(new_study, step_size=2e-5)]) != fingerprint([old_study])
