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
Where a study runs: the runner's backends, chosen and sized for this machine.

A backend runs batches of cases for runner.run_cases(): SerialBackend (in this
process), PoolBackend (a local process pool) or DaskBackend (a Dask cluster; Dask is
imported only by DaskBackend). open_backend() gives a DaskBackend on an existing
cluster (scheduler tcp://HOST:PORT) or on a local cluster of workers processes, or
without dask a PoolBackend where the command allows it. A backend receives cases and
the function that evaluates them; it builds none (cases.run_samples runs sampled valves
on one).

Sizes are bounded before anything is allocated or started: a study of more than
MAX_RUNS runs, or one whose runs would not fit in the memory available here
(BYTES_PER_RUN each, in this process), is refused, as is a local cluster of more than
WORKERS_PER_CORE workers per core or more than the memory holds (BYTES_PER_WORKER each).
"""

import os
import sys

from valve_sim.analysis.studies.results import case_index
from valve_sim.core.errors import StudyError
from valve_sim.core.extras import EXTRAS, require
from valve_sim.core.input_files import size_text


PIP_INSTALL = f"pip install {EXTRAS['studies']}"
MAX_RUNS = 1_000_000
# [bytes] memory of one run in the client: its case and its row, about 2 KiB measured
# (tracemalloc, 10,000 tolerance cases and rows), doubled for the results on their way
BYTES_PER_RUN = 4096
WORKERS_PER_CORE = 4
BYTES_PER_WORKER = 256 * 1024 * 1024  # [bytes] a Dask worker process with the model loaded
CORES = os.cpu_count() or 1
LOOPBACK = '127.0.0.1'  # where every part of a local cluster listens


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
    return case_index(batch[0]), case_index(batch[-1])


def open_backend(command, scheduler=None, workers=CORES, dashboard=None, pool_fallback=False):
    """
    Return the Dask backend of command (a name for messages); without dask a PoolBackend.

    scheduler: a running scheduler's address (None: a local cluster of workers
    processes); dashboard: HOST:PORT where the local cluster serves its dashboard
    (None: none). Without dask, a PoolBackend if pool_fallback and no scheduler;
    otherwise a missing dask raises StudyError saying what to pip-install.
    """
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
        require(f'{command} on Dask', 'studies', 'distributed', error=StudyError)
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
