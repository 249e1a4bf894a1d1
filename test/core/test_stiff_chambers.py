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
cycles (relief = inlet flow), and the same run at half the step.
"""

import numpy as np
import pytest
from valve_sim.core.coefficients import coefficients
from valve_sim.core.integrator import rk4_step, splits_needed, stiff_step
from valve_sim.core.model import P_C, P_S, relief_flows
from valve_sim.core.parameters import load_parameters
from valve_sim.core.rosenbrock import ros2_step
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE as L, simulate


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
    assert relieved == pytest.approx(20 * L, rel=5e-3)
    assert np.ptp(last[:, P_S]) > 1e3  # it does hunt: a limit cycle, not a steady state


def test_the_hunt_agrees_with_half_the_step(tiny, hunt):
    fine = simulate(tiny, FlowStep(5 * L, 20 * L, 0.25, END), step_size=5e-6)
    last = hunt.time > END - WINDOW
    for states in (hunt.states[last], fine.states[last]):
        assert np.all(np.isfinite(states))
    # The cycle's phase drifts with the step; its mean and amplitude do not.
    for index in (P_S, P_C):
        coarse, half = hunt.states[last, index], fine.states[last, index]
        assert np.mean(coarse) == pytest.approx(np.mean(half), rel=1e-3)
        assert np.ptp(coarse) == pytest.approx(np.ptp(half), rel=0.05)


def test_a_stiff_step_is_the_limit_of_many_rk4_sub_steps(tiny):
    """Where RK4 needs > 1024 sub-steps, ROS2's sub-steps end where 4096 RK4 sub-steps do."""
    c, q = coefficients(tiny), 20 * L
    # The hunt's state where main diverged (0.90 s with a 10 ns floor): the poppet near its seat.
    state = (7.09975e6, 3.92658e6, 3.20466e6, 3.17308e6, 9.46628e-5, -0.0474709, 2.69317e-6,
             -0.0371347)
    assert splits_needed(state, c, 1e-5, 0.0, q, 1) > 1024
    reached, accurate = stiff_step(state, q, 0.0, c, 1e-5)
    assert accurate
    fine = state
    for _ in range(4096):
        fine = rk4_step(fine, q, 0.0, c, 1e-5 / 4096)
    assert np.max(np.abs(np.subtract(reached, fine)[:4])) < 1e-5 * c.burst_pressure
    # ROS2 is L-stable: a chamber 1e4 times faster than the step lands on its quasi-static
    # pressure, where RK4 at the whole step explodes.
    once = ros2_step(state, q, 0.0, c, 1e-5)
    assert np.all(np.isfinite(once)) and abs(once[P_C] - fine[P_C]) < 1e-3 * c.burst_pressure
