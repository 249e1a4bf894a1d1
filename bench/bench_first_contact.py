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

"""Time what a new user waits for: set-up, the demo cold and warm, the tests (issue 8)."""

# The summary above is also this script's --help description.
#
#     python3 bench/bench_first_contact.py [--no-tests] [--json out/bench_first_contact.json]
#
# Clones this repository's committed HEAD into a temporary folder (no .venv, no
# compiled kernels: numba caches beside the sources, so a clone is cold) and times
# there, one after the other, with the system's python3:
#
# 1. first set-up: run.py creating .venv and installing valve_sim and its
#    dependencies (what the first `python3 run.py ...` does before its command);
# 2. cold demo: `python3 run.py demo`, its kernels compiled on this first run;
# 3. warm demo: `python3 run.py demo` again;
# 4. tests: `python3 run.py test -q` (unless --no-tests).
#
# Each must succeed (exit code 0). docs/benchmarks.md's first-contact timings come
# from this script; the load average at start and end is printed, since other work
# on the machine shows in every figure. pip's downloads come from this machine's
# package index and cache.

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time


REPO = Path(__file__).resolve().parent.parent


def timed(label, command, cwd):
    """Run command in cwd (output to a log there); return its wall time [s] or exit."""
    log = cwd.parent / f'{label.replace(" ", "_")}.log'
    started = time.perf_counter()
    with open(log, 'w') as stream:
        code = subprocess.call(command, cwd=cwd, stdout=stream, stderr=subprocess.STDOUT)
    seconds = time.perf_counter() - started
    if code != 0:
        sys.exit(f'{label} failed with exit code {code}:\n{log.read_text()[-3000:]}')
    print(f'{label:<14}{seconds:8.1f} s', flush=True)
    return seconds


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--no-tests', action='store_true', help='skip timing the test suite')
    parser.add_argument('--json', type=Path, help='also write the figures as JSON')
    args = parser.parse_args()
    load_start = os.getloadavg()
    python = 'python3'
    figures = {}
    with tempfile.TemporaryDirectory(prefix='first_contact_') as folder:
        clone = Path(folder) / 'valve_sim'
        subprocess.run(['git', 'clone', '-q', str(REPO), str(clone)], check=True)
        commit = subprocess.run(
            ['git', 'rev-parse', '--short', 'HEAD'], cwd=clone, capture_output=True, text=True
        ).stdout.strip()
        print(f'fresh clone of {commit} in {clone}')
        figures['first set-up'] = timed(
            'first set-up', [python, '-c', 'import run; run.ensure_environment()'], clone
        )
        for kind in ('cold', 'warm'):
            figures[f'{kind} demo'] = timed(
                f'{kind} demo', [python, 'run.py', 'demo', '--out', kind], clone
            )
        if not args.no_tests:
            figures['tests'] = timed(
                'tests', [python, 'run.py', 'test', '-q', '-p', 'no:cacheprovider'], clone
            )
    print(f'load average {load_start[0]:.2f} at start, {os.getloadavg()[0]:.2f} at end')
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(
            json.dumps({'commit': commit, 'load_average_start': load_start, **figures}, indent=2)
            + '\n'
        )
    return 0


if __name__ == '__main__':
    sys.exit(main())
