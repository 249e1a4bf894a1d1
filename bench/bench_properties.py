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
#     .venv/bin/python bench/bench_properties.py [--cases 300] [--seed 0] [--catalogue]
#
# The strategy of test/core/test_properties.py (valve_cases: the reference valve with
# seven parameters scaled 0.5-2x, a preset of 3-10 MPa, up to two faults of random
# severity, flows of 0.5-25 L/min, tank pressures 0-10 MPa, steps and ramps), drawn
# --cases times from --seed, each checked by envelope.property_report (finite,
# deterministic, a quarter step agrees, no invariant alarm). Prints every finding with
# its case; exit code 1 if any. A finding becomes a regression test. Reported apart, not
# as findings: cavitation alarms (a chamber below the vapour pressure, the model's
# cavity approximation in use) and runs that start at an unstable equilibrium (their
# quarter step is not compared; their other checks hold).
#
# --catalogue: catalogue_cases instead, every model parameter of the catalogue free within its
# limits (their corners drawn often), step sizes 0.1-100 us. Most such valves are refused
# before any run (an order of diameters, no cracking point, a step the valve cannot take):
# the refusals are counted by reason, so that the coverage is visible. A case's end time is
# cut to at most MAX_CASE_STEPS steps (reported as cut short).

import argparse
from collections import Counter
from pathlib import Path
import sys
import time

from hypothesis import given, HealthCheck, seed, settings
from valve_sim.analysis.steps.envelope import property_report
from valve_sim.core.errors import ParameterError, SteadyStateError
from valve_sim.core.parameters import load_parameters
from valve_sim.core.steady_state import steady_state
from valve_sim.core.step_check import check_integrable

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'test' / 'core'))
from test_properties import catalogue_cases, valve_cases  # noqa: E402,I100 (one copy)

REFERENCE = load_parameters().params
CATALOGUE_STEPS = (1e-7, 1e-6, 1e-5, 1e-4)
END_TIME = 0.3  # [s] property_findings' run length
MAX_CASE_STEPS = 200_000


def refusal(params, faults, step, initial_flow, initial_tank):
    """Return why a case is refused before its run (its first words, no numbers), or None."""
    try:
        steady_state(params, initial_flow, faults, initial_tank, stable=False)
        check_integrable(params, step, faults)
    except (ParameterError, SteadyStateError) as error:
        words = str(error).split(':')[0].split()
        return ' '.join(word for word in words if not any(ch.isdigit() for ch in word))
    return None


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--cases', type=int, default=300)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--catalogue', action='store_true',
                        help='draw every parameter over the whole catalogue (catalogue_cases)')
    args = parser.parse_args()
    began, tried, findings, refused, cut = time.perf_counter(), [0], [], Counter(), [0]
    alarms, unstable = [], []
    cases = (
        catalogue_cases(free=(1, 30), steps=CATALOGUE_STEPS) if args.catalogue
        else valve_cases().map(lambda case: (*case, 1e-5))
    )

    @seed(args.seed)
    @settings(max_examples=args.cases, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(cases)
    def campaign(case):
        params, faults, *inputs, step = case
        tried[0] += 1
        reason = refusal(params, faults, step, inputs[0], inputs[2])
        if reason:
            refused[reason] += 1
            return
        end_time = min(END_TIME, MAX_CASE_STEPS * step)
        cut[0] += end_time < END_TIME
        report = property_report(params, faults, *inputs, end_time=end_time, step_size=step)
        changed = {k: v for k, v in params.items() if v != REFERENCE.get(k)}
        case = (changed, faults.describe() or 'healthy', inputs, step)
        for kind, found, listed in (('finding', report.findings, findings),
                                    ('cavitation alarm', report.alarms, alarms),
                                    ('unstable start', [report.unstable_start], unstable)):
            if any(found):
                listed.append((*case, found))
                print(f'{kind}: {listed[-1]}', flush=True)

    campaign()
    print(f'{tried[0]} cases tried in {time.perf_counter() - began:.0f} s: '
          f'{sum(refused.values())} refused before the run, {cut[0]} runs cut short to '
          f'{MAX_CASE_STEPS} steps, {len(findings)} with findings; apart: {len(alarms)} with '
          f'cavitation alarms, {len(unstable)} starting at an unstable equilibrium')
    for reason, count in refused.most_common():
        print(f'  refused {count}x: {reason}')
    return 1 if findings else 0


if __name__ == '__main__':
    sys.exit(main())
