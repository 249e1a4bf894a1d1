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

"""Benchmark the command line's start-up: `valve-sim --help` and every `valve-sim CMD --help`."""

# The summary above is also this script's --help description.
#
#     python bench/bench_cli.py [--repeats 7] [--json out/bench_cli.json]
#
# Wall time of each command as a user runs it (the installed valve-sim script of this
# Python's environment), next to two floors measured in the same run: the bare
# interpreter (python -c pass) and python -c "import numpy". Runs are interleaved
# (one of each per round), so load from other work spreads over all of them;
# medians and maxima are printed, with the load average at start and end.
# Target (issue 8): every help <= 1 s on the development machine (2 cores).

import argparse
import json
import os
from pathlib import Path
import shutil
import statistics
import subprocess
import sys
import time

from valve_sim.commands.cli import SUBCOMMANDS


def commands():
    """Return {label: argv}: the floors, then the command line's helps."""
    script = shutil.which('valve-sim', path=str(Path(sys.executable).parent))
    cli = [script] if script else [sys.executable, '-m', 'valve_sim.commands.cli']
    return {
        'python -c pass (floor)': [sys.executable, '-c', 'pass'],
        'python -c "import numpy"': [sys.executable, '-c', 'import numpy'],
        'valve-sim --help': cli + ['--help'],
        **{f'valve-sim {name} --help': cli + [name, '--help'] for name in SUBCOMMANDS},
    }


def wall_time(argv):
    """Run argv to the end; return its wall time [s] (it must succeed)."""
    started = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - started


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeats', type=int, default=7, help='rounds (default 7)')
    parser.add_argument('--json', type=Path, help='also write the figures as JSON')
    args = parser.parse_args()
    load_start = os.getloadavg()
    runs = commands()
    times = {label: [] for label in runs}
    for _ in range(args.repeats):
        for label, argv in runs.items():
            times[label].append(wall_time(argv))
    figures = {
        label: {'median_s': statistics.median(values), 'max_s': max(values)}
        for label, values in times.items()
    }
    print(f'{"command":<34}{"median":>9}{"max":>9}')
    for label, f in figures.items():
        print(f'{label:<34}{f["median_s"]:8.2f}s{f["max_s"]:8.2f}s')
    print(f'load average {load_start[0]:.2f} at start, {os.getloadavg()[0]:.2f} at end')
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(
            json.dumps({'load_average_start': load_start, **figures}, indent=2) + '\n'
        )
    return 0


if __name__ == '__main__':
    sys.exit(main())
