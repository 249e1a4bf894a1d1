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

"""Property campaign: many random valves, faults and inputs; cases tried and what they broke."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_properties.py [--cases 300] [--seed 0]
#
# The strategy of test/core/test_properties.py (valve_cases: the reference valve with
# seven parameters scaled 0.5-2x, a preset of 3-10 MPa, up to two faults of random
# severity, flows of 0.5-25 L/min, tank pressures 0-10 MPa, steps and ramps), drawn
# --cases times from --seed, each checked by envelope.property_findings (finite,
# deterministic, a quarter step agrees, no invariant alarm). Prints every finding with
# its case; exit code 1 if any. A finding becomes a regression test.

import argparse
from pathlib import Path
import sys
import time

from hypothesis import given, HealthCheck, seed, settings
from valve_sim.analysis.steps.envelope import property_findings

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'test' / 'core'))
from test_properties import valve_cases  # noqa: E402,I100 (the suite's strategy, one copy)


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--cases', type=int, default=300)
    parser.add_argument('--seed', type=int, default=0)
    args = parser.parse_args()
    began, tried, findings = time.perf_counter(), [0], []

    @seed(args.seed)
    @settings(max_examples=args.cases, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(valve_cases())
    def campaign(case):
        params, faults, *inputs = case
        tried[0] += 1
        found = property_findings(params, faults, *inputs)
        if found:
            findings.append((faults.describe() or 'healthy', inputs, found))
            print(f'finding: {findings[-1]}', flush=True)

    campaign()
    print(f'{tried[0]} cases tried in {time.perf_counter() - began:.0f} s, '
          f'{len(findings)} with findings')
    return 1 if findings else 0


if __name__ == '__main__':
    sys.exit(main())
