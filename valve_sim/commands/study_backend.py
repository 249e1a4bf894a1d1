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
"""

import os
import sys

from valve_sim.analysis.study_cases import DEFAULT_PROTOCOL, PROTOCOLS
from valve_sim.core.errors import StudyError


PIP_INSTALL = "pip install 'dask[distributed]' SALib"


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
    parser.add_argument('--workers', type=int, default=os.cpu_count() or 1, metavar='N',
                        help='worker processes of the local cluster (default: all cores)')
    parser.add_argument('--batch-size', type=int, metavar='N',
                        help='runs per task (default: about 8 tasks per worker, at most 64 runs)')
    parser.add_argument('--resume', action='store_true',
                        help='keep the runs already in DIR/results.jsonl and compute only the '
                        'missing ones')
    parser.add_argument('--dashboard', nargs='?', const='127.0.0.1:0', metavar='HOST:PORT',
                        help="serve Dask's dashboard of the local cluster and print its address "
                        '(default 127.0.0.1:0: this machine only, a free port; 0.0.0.0:PORT '
                        'shows it to the network). Without it the local cluster has none, and '
                        'every part of it listens on 127.0.0.1 only')


def open_backend(args, command, pool_fallback=False):
    """
    Dask backend for the arguments; without dask a PoolBackend if pool_fallback.

    Otherwise a missing dask raises StudyError saying what to pip-install.
    """
    from valve_sim.analysis.study_runner import DaskBackend, PoolBackend

    if args.workers < 1 or (args.batch_size is not None and args.batch_size < 1):
        raise StudyError('--workers and --batch-size must be at least 1')
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
