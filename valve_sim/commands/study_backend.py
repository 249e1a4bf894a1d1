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
Options and backend shared by the study commands (study, tolerance, sensitivity).

--scheduler tcp://HOST:PORT uses an existing Dask cluster; without it a local
cluster of --workers processes runs on this machine. Results stream to
DIR/results.jsonl; --resume completes an interrupted study.

--protocol (analysis.study_cases.PROTOCOLS): held-preset sets every case's valve
to the preset before its test, frozen-preload keeps the preload of the parameter file.

Sizes are bounded before anything is allocated or started: a study of more than
MAX_RUNS runs, or one whose runs would not fit in the memory available here
(BYTES_PER_RUN each, in this process), is refused, as is a local cluster of more than
WORKERS_PER_CORE workers per core or more than the memory holds (BYTES_PER_WORKER each).
"""

import os
import sys

from valve_sim.analysis.study_cases import DEFAULT_PROTOCOL, PROTOCOLS
from valve_sim.commands.options import number
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


def add_protocol_arguments(parser):
    """--protocol and its short form --frozen-preload."""
    parser.add_argument('--protocol', choices=PROTOCOLS, default=DEFAULT_PROTOCOL,
                        help='held-preset: preload re-solved per case, the preset held '
                        '(default, the paper); frozen-preload: the preload of the parameter '
                        'file in every case')
    parser.add_argument('--frozen-preload', dest='protocol', action='store_const',
                        const='frozen-preload', help='same as --protocol frozen-preload')


def add_runner_arguments(parser):
    """--scheduler, --workers, --batch-size and --resume."""
    parser.add_argument('--scheduler', metavar='tcp://HOST:PORT',
                        help='address of a running Dask scheduler (default: a local cluster '
                        'on this machine)')
    parser.add_argument('--workers', type=number('a worker count', '', 1, 10**6, integer=True),
                        default=CORES, metavar='N',
                        help='worker processes of the local cluster (default: all cores; at '
                        f'most {WORKERS_PER_CORE} per core, {size_text(BYTES_PER_WORKER)} '
                        'of memory each)')
    parser.add_argument('--batch-size', metavar='N',
                        type=number('a batch size', '', 1, MAX_RUNS, integer=True),
                        help='runs per task (default: about 8 tasks per worker, at most 64 runs)')
    parser.add_argument('--resume', action='store_true',
                        help='keep the runs already in DIR/results.jsonl and compute only the '
                        'missing ones')
    parser.add_argument('--dashboard', nargs='?', const='127.0.0.1:0', metavar='HOST:PORT',
                        type=dashboard_address,
                        help="serve Dask's dashboard of the local cluster and print its address "
                        '(default 127.0.0.1:0: this machine only, a free port; 0.0.0.0:PORT '
                        'shows it to the network). Without it the local cluster has none, and '
                        'every part of it listens on 127.0.0.1 only')


def dashboard_address(text):
    """Parse --dashboard's HOST:PORT, PORT in [0, 65535] (argparse type)."""
    from argparse import ArgumentTypeError

    host, colon, port = text.strip().rpartition(':')
    if not (colon and host and port.isdigit() and int(port) <= 65535):
        raise ArgumentTypeError(f'must be HOST:PORT with a PORT in [0, 65535], got {text!r}')
    return f'{host}:{int(port)}'


dashboard_address.bounds = 'HOST:PORT, PORT in [0, 65535]'


def open_backend(args, command, pool_fallback=False):
    """
    Dask backend for the arguments; without dask a PoolBackend if pool_fallback.

    Otherwise a missing dask raises StudyError saying what to pip-install.
    """
    from valve_sim.analysis.study_runner import DaskBackend, PoolBackend

    check_workers(args.workers)
    try:
        import distributed  # noqa: F401  (is it installed?)
    except ImportError:
        if pool_fallback and not args.scheduler:
            print(
                f'{command}: dask is not installed: running on a local process pool '
                f'({PIP_INSTALL} for clusters)',
                file=sys.stderr,
            )
            return PoolBackend(args.workers)
        raise StudyError(f'{command} runs on Dask, which is not installed: {PIP_INSTALL}')
    dashboard = getattr(args, 'dashboard', None)
    backend = DaskBackend(args.scheduler, args.workers, dashboard=dashboard)
    where = args.scheduler or 'a local cluster (listening on 127.0.0.1 only)'
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
