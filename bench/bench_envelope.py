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

"""Envelope sweep: presets 3-10 MPa, inlet flows 0-25 L/min, steps and ramps, from closed too."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_envelope.py [--json FILE]
#
# Every ordered pair of distinct flows of FLOWS (0 = the empty, closed valve as
# start, or the flow stopped as end) at every preset of PRESETS, as a step and as a
# RAMP_TIME ramp: valve_sim.analysis.envelope judges each run (relieves, pilot
# relieves, closed, stalled, diverged). The test suite runs a coarse subset
# (test/analysis/test_envelope.py); this is the full grid. Exit code 1 if any run stalled
# or diverged.

import argparse
from collections import Counter
import json
import sys
import time

from valve_sim.analysis.envelope import envelope_run
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import LITRE_PER_MINUTE


PRESETS = (3e6, 4e6, 5e6, 7e6, 8.5e6, 10e6)  # [Pa]
FLOWS = (0.0, 1.0, 5.0, 10.0, 15.0, 20.0, 25.0)  # [L/min]
RAMP_TIME = 0.1  # [s]


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--json', metavar='FILE', help='write every run as JSON')
    args = parser.parse_args()
    params = load_parameters().params
    began, runs = time.perf_counter(), []
    for preset in PRESETS:
        for initial in FLOWS:
            for final in FLOWS:
                if initial == final:
                    continue
                for ramp in (0.0, RAMP_TIME):
                    run = envelope_run(
                        params, preset, initial * LITRE_PER_MINUTE, final * LITRE_PER_MINUTE, ramp
                    )
                    runs.append(run)
                    if not run.good:
                        print(
                            f'{run.outcome}: preset {preset / 1e6:g} MPa, {initial:g} -> '
                            f'{final:g} L/min, ramp {ramp:g} s: {run.message}',
                            flush=True,
                        )
    elapsed = time.perf_counter() - began
    counts = Counter(run.outcome for run in runs)
    print(
        f'{len(runs)} runs in {elapsed:.0f} s: '
        + ', '.join(f'{outcome} {count}' for outcome, count in sorted(counts.items()))
    )
    if args.json:
        with open(args.json, 'w') as stream:
            json.dump(
                [
                    {
                        'preset_pressure': run.preset_pressure,
                        'initial_flow': run.initial_flow,
                        'final_flow': run.final_flow,
                        'ramp_time': run.ramp_time,
                        'outcome': run.outcome,
                        'end_pressure': run.end_pressure,
                        'steady_pressure': run.steady_pressure,
                        'message': run.message,
                    }
                    for run in runs
                ],
                stream,
                indent=1,
            )
    return 0 if all(run.good for run in runs) else 1


if __name__ == '__main__':
    sys.exit(main())
