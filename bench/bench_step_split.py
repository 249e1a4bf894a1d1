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

"""Cost of choosing RK4's sub-steps (stiffness bound, step doubling) per tick, against plain."""

# The summary above is also this script's --help description.
#
#     .venv/bin/python bench/bench_step_split.py [--repeats 7]
#
# integrator.rk4_steps chooses each step's sub-steps: the stiffness bound every step,
# the step-doubling error estimate every CHECK_EVERY steps and when an input moves.
# The kernel itself is timed on the paper's 1.25 s run, choosing as it does
# (check_every omitted: the compiled constant CHECK_EVERY), choosing fully every
# step, and not at all (check_every 0: plain RK4, the baseline), alternately in one
# process; the best of --repeats each, also per 1 ms tick of valve_node (100 steps
# of 10 us) against its real-time budget of 1 ms. Then the same for the stiffest of
# issue 40's cases (a broken pilot spring at 5 L/min), whose steps are split: there
# plain RK4 gives a wrong answer (a numerical limit cycle), so only the cost is shown.
# Last, 1 ms ticks of a valve whose hunt needs the stiff step (a 1 mm^3 poppet chamber)
# beside the reference valve's: mean, 99th percentile and worst tick.

import argparse
from dataclasses import replace
import sys
import time

import numpy as np
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP
from valve_sim.core.coefficients import coefficients
from valve_sim.core.faults import HEALTHY
from valve_sim.core.integrator import CHECK_EVERY, rk4_steps
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import LITRE_PER_MINUTE, step_flows
from valve_sim.core.steady_state import steady_state


def timed(variants, start, flows, tanks, c, repeats):
    """Return ({name: best seconds}, {name: final state}) of rk4_steps per variant."""
    record = np.empty((0, 8))
    for extra in variants.values():  # compile each variant
        rk4_steps(start.copy(), flows[:10], tanks[:10], c, 1e-5, 1, np.empty((10, 8)), *extra)
    best, finals = dict.fromkeys(variants, np.inf), {}
    for _ in range(repeats):
        for name, extra in variants.items():
            state = start.copy()
            began = time.perf_counter()
            rk4_steps(state, flows, tanks, c, 1e-5, len(flows) + 1, record, *extra)
            best[name] = min(best[name], time.perf_counter() - began)
            finals[name] = state
    return best, finals


def report(title, best, steps, baseline):
    """Print each variant's time, per 1 ms tick (100 steps) and against baseline."""
    print(title)
    for name, seconds in best.items():
        tick = seconds / steps * 100
        print(
            f'  {name:<34} {seconds * 1e3:8.1f} ms, {tick * 1e6:7.1f} us per 1 ms tick '
            f'({tick / 1e-3:.1%} of it)'
            + (f', x{seconds / best[baseline]:.3f} of plain RK4' if baseline else '')
        )


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--repeats', type=int, default=7)
    args = parser.parse_args()
    params = load_parameters().params
    c, flows = coefficients(params), step_flows(REFERENCE_FLOW_STEP, 1e-5)
    start = steady_state(params, REFERENCE_FLOW_STEP.initial_flow)
    tanks = np.zeros(len(flows))  # the tank at ambient
    plain = 'not chosen (plain RK4)'
    variants = {
        f'chosen as run (every {CHECK_EVERY})': (),
        'fully chosen every step': (1,),
        plain: (0,),
    }
    best, finals = timed(variants, start, flows, tanks, c, args.repeats)
    report("the paper's step, 1.25 s of model time:", best, len(flows), plain)
    gap = max(np.max(np.abs(final - finals[plain])) for final in finals.values())
    print(f'  final states: largest difference to plain RK4 {gap:.3g} (SI)')
    broken_fault = HEALTHY.changed({'pilot_spring_broken': True})
    broken = coefficients(params, broken_fault)
    flows = np.full(50_000, 5 * LITRE_PER_MINUTE)
    start = steady_state(params, 5 * LITRE_PER_MINUTE, broken_fault)
    as_run = {f'chosen as run (every {CHECK_EVERY})': ()}
    best, _ = timed(as_run,
                    start, flows, np.zeros(len(flows)), broken, args.repeats)
    report('broken pilot spring at 5 L/min, 0.5 s at its steady state (split):', best,
           len(flows), None)
    ticks(params)
    return 0


def ticks(params, end=0.9):
    """
    Print the cost per 1 ms tick, 100 steps, of the hunting 1 mm^3 poppet chamber.

    Its steps that RK4 cannot take in 1024 sub-steps are ROS2's (integrator.stiff_step):
    the mean and the worst tick over the paper's step 5 -> 20 L/min to end [s], beside
    the reference valve's under the same inputs, in one process.
    """
    flows = step_flows(replace(REFERENCE_FLOW_STEP, end_time=end), 1e-5)
    tanks, record = np.zeros(100), np.empty((0, 8))
    print(f"1 ms ticks of the paper's step to {end} s (budget 1000 us):")
    for name, valve in (('reference valve', params),
                        ('1 mm^3 poppet chamber (hunts; ROS2 steps)', {
                            **params, 'poppet_chamber_volume': 1e-9})):
        c = coefficients(valve)
        state = steady_state(valve, REFERENCE_FLOW_STEP.initial_flow, stable=False)
        rk4_steps(state.copy(), flows[:100], tanks, c, 1e-5, 101, record)  # compiled
        costs = []
        for k in range(0, len(flows) - 99, 100):
            began = time.perf_counter()
            rk4_steps(state, flows[k:k + 100], tanks, c, 1e-5, 101, record)
            costs.append(time.perf_counter() - began)
        costs = np.array(costs) * 1e6
        print(f'  {name:<44} mean {np.mean(costs):7.1f} us, 99th percentile '
              f'{np.percentile(costs, 99):7.1f} us, worst {np.max(costs):7.1f} us')


if __name__ == '__main__':
    sys.exit(main())
