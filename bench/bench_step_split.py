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

"""Cost of the stiffness check that splits RK4 steps: the kernel against plain RK4."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_step_split.py [--repeats 7]
#
# integrator.rk4_steps asks model.fastest_chamber_rate every CHECK_EVERY steps
# whether the step must be split (it never must at the paper's operating points).
# The baseline here is rk4_steps without that question (integrator.rk4_step in the
# same loop with the same sanity check and record bookkeeping), timed alternately
# with rk4_steps on the paper's 1.25 s run in one process; the best of --repeats
# each. valve_node pays the same ratio per tick.

import argparse
import sys
import time

import numpy as np
from valve_sim.analysis.paper import REFERENCE_SCENARIO
from valve_sim.core.integrator import rk4_step, rk4_steps, state_is_sane
from valve_sim.core.jit import jit
from valve_sim.core.model import coefficients
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import step_flows
from valve_sim.core.steady_state import steady_state


@jit
def plain_rk4(state, inlet_flows, c, step, record_every, record):
    """Baseline: rk4_steps as it was before the check (one RK4 step per flow, same checks)."""
    n = state.shape[0]
    scratch = np.empty((5, n))
    row = 0
    until_record = record_every
    for k in range(inlet_flows.shape[0]):
        rk4_step(
            state, inlet_flows[k], c, step, scratch[0], scratch[1], scratch[2], scratch[3],
            scratch[4]
        )
        if not state_is_sane(state):
            return k
        until_record -= 1
        if until_record == 0:
            until_record = record_every
            if row < record.shape[0]:
                record[row, :] = state
                row += 1
    return inlet_flows.shape[0]


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeats', type=int, default=7)
    args = parser.parse_args()
    params, _ = load_parameters()
    c, flows = coefficients(params), step_flows(REFERENCE_SCENARIO, 1e-5)
    start = steady_state(params, REFERENCE_SCENARIO.initial_flow)
    record = np.empty((0, 8))
    checked_state, plain_state = start.copy(), start.copy()
    rk4_steps(checked_state, flows[:10], c, 1e-5, 1, np.empty((10, 8)))  # compile
    plain_rk4(plain_state, flows[:10], c, 1e-5, 1, np.empty((10, 8)))
    best = {'rk4_steps (with the check)': np.inf, 'plain RK4': np.inf}
    for _ in range(args.repeats):
        for name in best:
            state = start.copy()
            began = time.perf_counter()
            if name == 'plain RK4':
                plain_rk4(state, flows, c, 1e-5, len(flows) + 1, record)
            else:
                rk4_steps(state, flows, c, 1e-5, len(flows) + 1, record)
            best[name] = min(best[name], time.perf_counter() - began)
            if name == 'plain RK4':
                plain_state = state
            else:
                checked_state = state
    for name, seconds in best.items():
        print(f'{name:<28} {seconds * 1e3:8.1f} ms for 1.25 s of model time')
    ratio = best['rk4_steps (with the check)'] / best['plain RK4']
    print(f'ratio {ratio:.3f}; final states equal: {np.array_equal(checked_state, plain_state)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
