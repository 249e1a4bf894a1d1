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

"""Calibration time: the two-parameter bag fit and the derivation of the reference geometry."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_calibrate.py [--json FILE]
#
# 1. Bag fit: a rig-style bag (simulate --rig-topics, d_c +8 %, k_p -12 %, 1 kPa
#    noise, Float64 topics /rig/inlet_pressure and /rig/flowmeter), then
#    `valve-sim calibrate --bag ... --fit d_c,k_p` (3 starts). Target: <= 60 s.
# 2. The reference derivation: the command of docs/model.md (test_calibrate.py's
#    REFERENCE_COMMAND: nine dimensions, the design rules, 3 starts). Target: <= 180 s
#    (issue 28: test_calibrate.py re-runs it in CI).
# Wall time of each whole command (process start to exit) and the fit's own wall
# time and evaluation count from its report.json; the machine is shared, so the
# CPU time of the child process is printed too.

import argparse
import json
from pathlib import Path
import resource
import subprocess
import sys
import tempfile
import time


ROOT = Path(__file__).resolve().parents[1]
RIG = ['--topic-supply-pressure', '/rig/inlet_pressure', '--topic-inlet-flow', '/rig/flowmeter',
       '--clock', 'receive']
REFERENCE_ARGS = (
    '--params config/calibration/figure5_start.yaml --preset-pressure 7MPa '
    '--target-measures config/calibration/figure5.json --fit d_p,D_1,d_1,D_2,d_2,h,k_m,d_b,d_s '
    '--tie d_v=0.98*d_s --max-pilot-flow 1.2L/min --table2-decays --relieves d_c=-20 '
    '--land-margin 1e-3 --main-spring-rate 1e3:5e3 --main-spring-preload 20:100 '
    '--study-relieves --tolerance 1e-4'
).split()


def valve_sim(*args):
    """Run valve-sim; return (wall time [s], child CPU time [s])."""
    cpu_before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', *map(str, args)],
        check=True, cwd=ROOT, capture_output=True,
    )
    wall = time.perf_counter() - start
    cpu_after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (cpu_after.ru_utime - cpu_before.ru_utime) + (cpu_after.ru_stime - cpu_before.ru_stime)
    return wall, cpu


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--json', metavar='FILE', help='write the figures as JSON')
    args = parser.parse_args()
    results = {}
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        bag = folder / 'rig.mcap'
        valve_sim('simulate', '--set', 'd_c=1.08e-3', '--set', 'k_p=139040', '--mcap', bag,
                  '--rig-topics', '/rig/inlet_pressure,/rig/flowmeter', '--pressure-noise', '1000',
                  '--seed', '11')
        for name, arguments in (
            ('bag_fit', ['--bag', bag, *RIG, '--fit', 'd_c,k_p']),
            ('reference_geometry', REFERENCE_ARGS),
        ):
            out = folder / name
            wall, cpu = valve_sim('calibrate', *arguments, '--out', out, '--quiet')
            report = json.loads((out / 'report.json').read_text())
            results[name] = {
                'command_wall_s': wall,
                'command_cpu_s': cpu,
                'fit_wall_s': report['wall_time_s'],
                'evaluations': report['evaluations'],
            }
            print(
                f'{name}: {wall:.1f} s wall for the command ({cpu:.1f} s CPU), fit '
                f'{report["wall_time_s"]:.1f} s, {report["evaluations"]} model evaluations',
                flush=True,
            )
    target = results['bag_fit']['command_wall_s'] <= 60.0
    print(f'bag fit target <= 60 s: {"met" if target else "NOT met"}')
    target = results['reference_geometry']['command_wall_s'] <= 180.0
    print(f'reference derivation target <= 180 s: {"met" if target else "NOT met"}')
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
