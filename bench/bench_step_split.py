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

"""Cost of the stiffness check that splits RK4 steps: the kernel asking it, against not."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_step_split.py [--repeats 7]
#
# integrator.rk4_steps asks model.fastest_chamber_rate every CHECK_EVERY steps
# whether the step must be split (it never must at the paper's operating points).
# The kernel itself is timed on the paper's 1.25 s run, asking as it does
# (check_every omitted: the compiled constant CHECK_EVERY), every step, and only
# at the first step (the baseline: plain RK4 with the same state check and
# record bookkeeping), alternately in one process; the best of --repeats each.
# valve_node pays the same ratio per tick.

import argparse
import sys
import time

import numpy as np
from valve_sim.analysis.paper import REFERENCE_SCENARIO
from valve_sim.core.coefficients import coefficients
from valve_sim.core.integrator import CHECK_EVERY, rk4_steps
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import step_flows
from valve_sim.core.steady_state import steady_state


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeats', type=int, default=7)
    args = parser.parse_args()
    params = load_parameters().params
    c, flows = coefficients(params), step_flows(REFERENCE_SCENARIO, 1e-5)
    start = steady_state(params, REFERENCE_SCENARIO.initial_flow)
    tanks = np.zeros(len(flows))  # the tank at ambient
    record = np.empty((0, 8))
    variants = {
        f'asked every {CHECK_EVERY} steps (as run)': (),
        'asked every step': (1,),
        'asked once (plain RK4)': (len(flows) + 1,),
    }
    for extra in variants.values():  # compile each variant
        rk4_steps(start.copy(), flows[:10], tanks[:10], c, 1e-5, 1, np.empty((10, 8)), *extra)
    best = dict.fromkeys(variants, np.inf)
    finals = {}
    for _ in range(args.repeats):
        for name, extra in variants.items():
            state = start.copy()
            began = time.perf_counter()
            rk4_steps(state, flows, tanks, c, 1e-5, len(flows) + 1, record, *extra)
            best[name] = min(best[name], time.perf_counter() - began)
            finals[name] = state
    baseline = best['asked once (plain RK4)']
    for name, seconds in best.items():
        print(
            f'{name:<30} {seconds * 1e3:8.1f} ms for 1.25 s of model time '
            f'(x{seconds / baseline:.3f} of plain RK4)'
        )
    plain = finals['asked once (plain RK4)']
    same = all(np.array_equal(final, plain) for final in finals.values())
    print(f'final states equal: {same}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
