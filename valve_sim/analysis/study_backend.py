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
Where a study runs: the runner's backend chosen and sized for this machine.

open_backend() gives a DaskBackend on an existing cluster (scheduler tcp://HOST:PORT)
or on a local cluster of workers processes, or without dask a PoolBackend where the
command allows it (study_runner). run_samples() runs sampled valves on one.

Sizes are bounded before anything is allocated or started: a study of more than
MAX_RUNS runs, or one whose runs would not fit in the memory available here
(BYTES_PER_RUN each, in this process), is refused, as is a local cluster of more than
WORKERS_PER_CORE workers per core or more than the memory holds (BYTES_PER_WORKER each).
"""

import os
import sys

from valve_sim.analysis.study_cases import sample_cases
from valve_sim.core.errors import StudyError
from valve_sim.core.input_files import size_text


PIP_INSTALL = "pip install 'dask[distributed]' SALib"
MAX_RUNS = 1_000_000
# [bytes] memory of one run in the client: its case and its row, about 2 KiB measured
# (tracemalloc, 10,000 tolerance cases and rows), doubled for the results on their way
BYTES_PER_RUN = 4096
WORKERS_PER_CORE = 4
BYTES_PER_WORKER = 256 * 1024 * 1024  # [bytes] a Dask worker process with the model loaded
CORES = os.cpu_count() or 1


def available_memory():
    """Return the memory available to a new allocation here [bytes] (MemAvailable)."""
    try:
        with open('/proc/meminfo') as stream:
            for line in stream:
                if line.startswith('MemAvailable:'):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return os.sysconf('SC_AVPHYS_PAGES') * os.sysconf('SC_PAGE_SIZE')


def check_runs(runs, what):
    """Raise StudyError unless runs (what: the option that asks for them) fit the limits."""
    check_fits(what, runs, 'runs', MAX_RUNS, BYTES_PER_RUN)


def check_fits(what, count, things, limit, each):
    """Raise StudyError unless count things, each bytes, are within limit and the memory."""
    need, available = count * each, available_memory()
    if count > limit or need > available:
        raise StudyError(
            f'{what} asks for {count:,} {things}, which would need about {size_text(need)} '
            f'of memory here ({size_text(each)} each); the limit is {limit:,} {things} and '
            f'what fits in the {size_text(available)} available'
        )


def open_backend(command, scheduler=None, workers=CORES, dashboard=None, pool_fallback=False):
    """
    Return the Dask backend of command (a name for messages); without dask a PoolBackend.

    scheduler: a running scheduler's address (None: a local cluster of workers
    processes); dashboard: HOST:PORT where the local cluster serves its dashboard
    (None: none). Without dask, a PoolBackend if pool_fallback and no scheduler;
    otherwise a missing dask raises StudyError saying what to pip-install.
    """
    from valve_sim.analysis.study_runner import DaskBackend, PoolBackend

    check_workers(workers)
    try:
        import distributed  # noqa: F401  (is it installed?)
    except ImportError:
        if pool_fallback and not scheduler:
            print(
                f'{command}: dask is not installed: running on a local process pool '
                f'({PIP_INSTALL} for clusters)',
                file=sys.stderr,
            )
            return PoolBackend(workers)
        raise StudyError(f'{command} runs on Dask, which is not installed: {PIP_INSTALL}')
    backend = DaskBackend(scheduler, workers, dashboard=dashboard)
    where = scheduler or 'a local cluster (listening on 127.0.0.1 only)'
    print(f'{command}: {backend.workers} Dask workers on {where}', file=sys.stderr)
    if dashboard:
        link = backend.start().dashboard_link  # started now, to say where to look
        print(f'{command}: Dask dashboard: {link or "none (the scheduler serves none)"}',
              file=sys.stderr)
    return backend


def check_workers(workers):
    """Raise StudyError unless a local cluster of workers processes fits this machine."""
    limit = WORKERS_PER_CORE * CORES  # WORKERS_PER_CORE a core
    check_fits(f'--workers {workers}', workers, 'worker processes', limit, BYTES_PER_WORKER)


def run_samples(
    label, params, names, values, preset, step_size, results_path, scheduler=None,
    workers=CORES, dashboard=None, resume=False, batch_size=None,
):
    """
    Run the sampled valves on the study runner; return their rows in sample order.

    values: one row per valve, one column per parameter of names; preset [Pa] or None
    (study_cases.sample_cases). Rows stream to results_path (resume continues it); the
    backend is open_backend()'s for command label.
    """
    from valve_sim.analysis.study_runner import run_cases

    backend = open_backend(label, scheduler, workers, dashboard)
    try:
        results, _ = run_cases(
            sample_cases(params, names, values, preset, step_size),
            results_path,
            backend,
            resume,
            batch_size,
            label=label,
        )
    finally:
        backend.close()
    return [results[index] for index in range(len(values))]
