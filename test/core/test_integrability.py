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
Issue 40's last classes: what integrates, what is an overpressure, what is refused before a run.

Each failed on main ca4e51d: an inner chamber's overpressure called a divergence, an unstable
equilibrium accepted as a start, a 0.1 g main valve at 100 us diverging, a valve that cannot
pass its own max_inlet_flow accepted.
"""

import numpy as np
import pytest
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import OverpressureError, SteadyStateError
from valve_sim.core.faults import HEALTHY
from valve_sim.core.integrator import step_problem
from valve_sim.core.model import P_P, P_S
from valve_sim.core.parameters import load_parameters
from valve_sim.core.realtime_model import RealTimeModel, Status
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE as L, simulate, TankPressure
from valve_sim.core.steady_state import steady_state
from valve_sim.core.step_check import check_integrable


@pytest.fixture(scope='module')
def reference():
    return load_parameters().params


HALF_BLOCKED_DAMPING = HEALTHY.changed({'damping_orifice_blockage': 0.5})


def test_a_tank_step_near_burst_overpressures_the_pilot_chamber_a_ramp_does_not(reference):
    # The tank's 34 MPa slams the main valve open; its back face compresses V_p 1.9 MPa
    # beyond the tank (converged with the step: 35.92 MPa): an overpressure of p_p.
    with pytest.raises(OverpressureError, match='pilot_pressure = .* exceeds burst') as error:
        simulate(reference, FlowStep(5 * L, 5 * L, 0.1, 0.11), 1e-5, 1e-4,
                 HALF_BLOCKED_DAMPING, tank=TankPressure(0.0, 34e6, 0.1))
    assert error.value.chamber == 'pilot_pressure'
    ramped = simulate(reference, FlowStep(5 * L, 5 * L, 0.1, 0.12, 1e-3), 1e-5, 1e-4,
                      HALF_BLOCKED_DAMPING, tank=TankPressure(0.0, 34e6, 0.1, 1e-3))
    assert ramped.states[:, P_P].max() < reference['burst_pressure']


def test_the_live_model_reads_the_chamber_that_passed_burst_at_burst(reference):
    model = RealTimeModel(reference, 1e-5, 5 * L, HALF_BLOCKED_DAMPING)
    model.start(0)
    outcome = model.update(100_000_000, 5 * L, 10**9, tank_pressure=34e6)
    assert outcome.status is Status.FAILURE and outcome.overpressure
    assert model.saturated_chamber == 'pilot_pressure'
    read = model.output_state()
    assert read[P_P] == reference['burst_pressure'] and read[P_S] == model.state[P_S]
    model.reset(5 * L, 0.0)
    assert model.saturated_chamber is None and model.output_state() is model.state


def test_an_unstable_equilibrium_is_no_steady_state_but_a_run_may_start_there(reference):
    # Bearing orifices fully blocked: every balance holds at the solver's state, fed by the
    # rod's leakage, yet a 762 Hz mode grows (a nudged run leaves it: docs/model.md).
    blocked = HEALTHY.changed({'bearing_orifice_blockage': 1.0})
    with pytest.raises(SteadyStateError, match=r'is unstable, a mode at 7\d\d.\d Hz grows'):
        steady_state(reference, 5 * L, blocked)
    start = steady_state(reference, 5 * L, blocked, stable=False)
    run = simulate(reference, FlowStep(5 * L, 5 * L, 0.01, 0.02), 1e-5, 1e-4, blocked)
    assert np.array_equal(run.states[0], start)


def test_a_light_main_valve_at_a_large_step_agrees_with_a_small_step(reference):
    # A 0.1 g main valve rings at 250 kHz on its chambers' fluid springs: the split steps
    # follow it (main ca4e51d: diverged at 100 us, the bound knew only the chambers).
    light = {**reference, 'main_valve_mass': 1e-4}
    flows = FlowStep(5 * L, 20 * L, 0.02, 0.06)
    large, small = (simulate(light, flows, step, 1e-3).states[-1] for step in (1e-4, 2.5e-5))
    assert large[P_S] == pytest.approx(small[P_S], rel=1e-6)


def test_a_valve_beyond_the_smallest_sub_step_is_refused_before_the_run(reference):
    # A 0.1 g main valve with a 1 mm^3 pilot chamber of stiff water and a heavy damper:
    # its bodies' rate needs sub-steps below integrator.MIN_SUB_STEP at 100 us.
    corner = {**reference, 'main_valve_mass': 1e-4, 'main_valve_damping': 1e4,
              'pilot_volume': 1e-9, 'bulk_modulus': 1e10}
    problem = step_problem(coefficients(corner), 1e-4)
    assert problem and 'cannot be integrated at step size 0.0001 s' in problem
    assert step_problem(coefficients(reference), 1e-4) is None


def test_a_valve_too_stiff_for_rk4_at_max_inlet_flow_is_accepted_and_runs(reference):
    # A 1 mm^3 intermediate chamber, bearing orifices half blocked: at max_inlet_flow the
    # chamber between the wide-open throttles would need 2 ns RK4 sub-steps. Refused before
    # stop 52; the stiff step (ROS2) integrates it (test_stiff_chambers.py checks how well),
    # so only a body that rings too fast is refused now (docs/model.md, "Step splitting").
    tiny = {**reference, 'intermediate_volume': 1e-9}
    faults = HEALTHY.changed({'bearing_orifice_blockage': 0.5})
    check_integrable(tiny, 1e-5, faults)
    model = RealTimeModel(tiny, 1e-5, 1 * L, faults)
    model.start(0)
    for tick in range(1, 6):
        outcome = model.update(tick * 1_000_000, tiny['max_inlet_flow'], 10**9)
        assert outcome.status is Status.PROGRESS, outcome.error
    assert np.isfinite(model.state).all()
