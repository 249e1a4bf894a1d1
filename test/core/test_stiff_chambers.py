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
Chambers the run drives stiffer than RK4's sub-steps allow: the stiff-stable step (ROS2).

The catalogue's smallest poppet chamber (1 mm^3) stepped 5 -> 20 L/min hunts around its
unstable 20 L/min equilibrium; as the poppet nears its seat the chamber relaxes at
4.6e8 1/s, beyond RK4 at 10 ns sub-steps: on main the run diverged at 0.67 s. Each
answer is judged independently of the integrator: the flow balance over whole hunting
cycles (relief = inlet flow), a stiff step against thousands of RK4 sub-steps. The same
hunt at finer steps converges (docs/model.md, "Step splitting"): checked once, not here.
"""

import numpy as np
import pytest
from valve_sim.core.coefficients import coefficients
from valve_sim.core.integrator import advance
from valve_sim.core.invariants import stored_volumes
from valve_sim.core.model import fastest_chamber_rate, P_C, P_S, relief_flows
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE as L, simulate
from valve_sim.core.steady_state import steady_state


END = 0.9  # [s] past main's divergence at 0.67 s
WINDOW = 0.2  # [s] the last stretch: ~140 cycles of the 698 Hz hunt


@pytest.fixture(scope='module')
def tiny():
    return dict(load_parameters().params, poppet_chamber_volume=1e-9)


@pytest.fixture(scope='module')
def hunt(tiny):
    return simulate(tiny, FlowStep(5 * L, 20 * L, 0.25, END))


def test_a_tiny_poppet_chamber_that_hunts_integrates_and_relieves_its_inlet_flow(tiny, hunt):
    c = coefficients(tiny)
    assert np.all(np.isfinite(hunt.states)) and hunt.time[-1] == pytest.approx(END)
    last = hunt.states[hunt.time > END - WINDOW]
    relieved = np.mean([sum(relief_flows(state, c, 0.0)) for state in last])
    # What the chambers store over the window (the hunt still grows) is not relieved.
    stored = np.sum(stored_volumes(last[-1], c) - stored_volumes(last[0], c)) / WINDOW
    assert relieved + stored == pytest.approx(20 * L, rel=1e-3)
    assert np.ptp(last[:, P_S]) > 1e3  # it does hunt: a limit cycle, not a steady state


def test_a_stiff_step_is_the_limit_of_many_rk4_sub_steps(tiny):
    """Where RK4 needs > 1024 sub-steps, ROS2's sub-steps end where 4096 RK4 sub-steps do."""
    c, q = coefficients(tiny), 20 * L
    # The hunt's state where RK4 gave up (0.90 s): the poppet near its seat, the chamber
    # relaxing at 1.5e8 1/s and 25 kPa off its quasi-static pressure (RK4's step doubling
    # asks for more than 1024 sub-steps of the 10 us step).
    state = np.array([7.09975e6, 3.92658e6, 3.20466e6, 3.17308e6, 9.46628e-5, -0.0474709,
                      2.69317e-6, -0.0371347])
    assert fastest_chamber_rate(state, c) > 1e8
    stiff, fine = state.copy(), state.copy()
    advance(stiff, [q], c, 1e-5)
    advance(fine, np.full(4096, q), c, 1e-5 / 4096)  # 2.4 ns: within RK4's own limit
    assert np.max(np.abs(stiff - fine)[:4]) < 1e-7 * c.burst_pressure  # 3.5 Pa
    assert abs(stiff[P_C] - state[P_C]) > 2e4  # the chamber moved: a real test of the step


def test_a_tiny_intermediate_chamber_integrates_up_to_max_inlet_flow():
    """The first case of the class: diverged at 3 ms when RK4 needed 2 ns sub-steps."""
    reference = load_parameters().params
    c = coefficients({**reference, 'intermediate_volume': 1e-9})
    start = steady_state(reference, 5 * L)
    coarse, fine = start.copy(), start.copy()
    advance(coarse, np.full(500, 100 * L), c, 1e-5)
    advance(fine, np.full(1000, 100 * L), c, 5e-6)
    assert np.max(np.abs(coarse - fine)[:4]) < 1e-5 * c.burst_pressure
