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
The tank pressure as the model's second input, offline (issue 30).

The flow balance of a run (inlet = relief flow + the rate the valve stores volume),
the cracking pressure's shift with back pressure (docs/model.md, "Back pressure")
against the steady-state solver, and the tank's limits as an input.
"""

import json
import subprocess
import sys

import numpy as np
import pytest
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import ParameterError, SteadyStateError
from valve_sim.core.faults import FaultSet
from valve_sim.core.model import P_C, P_S, relief_flows as model_relief_flows, X, Y
from valve_sim.core.simulation import (
    FlowStep,
    LITRE_PER_MINUTE,
    relief_flows,
    run_flows,
    simulate,
    step_flows,
    TankPressure,
)
from valve_sim.core.steady_state import cracking_pressure, steady_state


STEP = 1e-5  # [s] the reference step size
WORN_SEAT = FaultSet(seat_leakage_diameter=0.2e-3)  # a leak to the tank beside q_m2 and q_p
BAR = 1e5
FLOW_STEP = FlowStep(5 * LITRE_PER_MINUTE, 20 * LITRE_PER_MINUTE, step_time=0.005, end_time=0.06)


def stored_volume(params, states):
    """
    Volume the valve holds above its empty, closed state [m^3] at each row of states.

    The chambers' compression sum(V_i / beta p_i), less the volume the main valve's
    tank-facing area A_t gave the tank as it opened (A_t x), plus the poppet's seat
    area A_v y, which its spring chamber takes from the tank: docs/model.md, "The
    flow balance". Gauge pressures: a constant term does not change its rate.
    """
    c = coefficients(params)
    chambers = ('supply_volume', 'intermediate_volume', 'pilot_volume', 'poppet_chamber_volume')
    compliances = [params[name] / params['bulk_modulus'] for name in chambers]
    compressed = states[:, P_S:P_C + 1] @ np.array(compliances)
    return compressed - c.tank_force_area * states[:, X] + c.seat_area * states[:, Y]


def volume_balance(params, run, faults):
    """
    Return (inlet volume, relief volume, stored volume's change) [m^3] of a run.

    Each recorded interval (a step) holds its inputs, so the inlet volume is exact;
    the relief flow is integrated by the trapezoidal rule at the interval's own tank
    pressure (a tank step changes the flows to tank at once: a sample's relief flow
    differs on either side of it).
    """
    time, tank = run.time, run.tank_pressure
    inlet = float(np.sum(run.inlet_flow[1:] * np.diff(time)))
    c = coefficients(params, faults)
    relieved = 0.0
    for k in range(len(time) - 1):
        start = sum(model_relief_flows(run.states[k], c, tank[k + 1]))
        end = sum(model_relief_flows(run.states[k + 1], c, tank[k + 1]))
        relieved += 0.5 * (start + end) * (time[k + 1] - time[k])
    stored = stored_volume(params, run.states)
    return inlet, relieved, float(stored[-1] - stored[0])


@pytest.mark.parametrize(
    'scenario, tank',
    [
        (FLOW_STEP, TankPressure()),
        (FLOW_STEP, TankPressure(4 * BAR)),
        (
            FlowStep(10 * LITRE_PER_MINUTE, 10 * LITRE_PER_MINUTE, end_time=0.06),
            TankPressure(1 * BAR, 6 * BAR, step_time=0.005, ramp_time=0.002),
        ),
        (
            FlowStep(10 * LITRE_PER_MINUTE, 10 * LITRE_PER_MINUTE, end_time=0.06),
            TankPressure(6 * BAR, 1 * BAR, step_time=0.005),
        ),
    ],
    ids=[
        'flow-step-tank-at-ambient', 'flow-step-tank-at-4-bar', 'tank-ramp-1-to-6-bar',
        'tank-step-6-to-1-bar',
    ],
)
def test_inlet_flow_is_the_relief_flow_plus_the_volume_stored(reference, scenario, tank):
    """
    Over a transient the inlet volume = relief volume + change of stored volume.

    The seat leaks (a fault), so all three flows to the tank take part. RK4 keeps
    this linear balance exactly; what is left is the trapezoidal rule's error on
    the relief flow, sampled every step: at 10 us 3e-6 of the inlet volume after the
    tank step (its fast transient now resolved by split steps), at 5 us, as run here,
    3e-7 (it falls as the sampling refines: quadrature, not a leak). Leaving out a flow to
    tank or a chamber moves it by per cents, the main valve's A_t x term by 5e-4, the
    poppet's A_v y term by 5e-6 to 1e-5: all beyond the 2e-6 allowed.
    """
    run = simulate(reference, scenario, STEP / 2, STEP / 2, WORN_SEAT, tank=tank)
    inlet, relieved, stored = volume_balance(reference, run, WORN_SEAT)
    parts = relief_flows(reference, run, WORN_SEAT)
    assert np.all(parts[:, 1:].min(axis=0) >= 0.0), 'a flow into the tank runs backwards'
    assert np.all(parts[:, 1:].max(axis=0) > 0.0), 'each of the three flows to tank takes part'
    np.testing.assert_allclose(parts[:, 0], parts[:, 1:].sum(axis=1), rtol=1e-12)
    assert abs(stored) > 0.01 * inlet, 'a transient that stores volume'
    assert inlet - relieved - stored == pytest.approx(0.0, abs=2e-6 * inlet)


def test_a_constant_back_pressure_relieves_what_flows_in_at_steady_state(reference):
    """At a steady state with the tank at 5 bar the relief flow is the inlet flow."""
    flow = 15 * LITRE_PER_MINUTE
    run = simulate(
        reference, FlowStep(flow, flow, end_time=1e-3), STEP, 1e-3, WORN_SEAT,
        tank=TankPressure(5 * BAR),
    )
    assert relief_flows(reference, run, WORN_SEAT)[0, 0] == pytest.approx(flow, rel=1e-7)


@pytest.fixture(scope='module')
def variant(reference):
    """Return a design not fitted: a stiffer pilot spring set lower, a narrower damping orifice."""
    return {
        **reference,
        'pilot_spring_stiffness': 1.5 * reference['pilot_spring_stiffness'],
        'pilot_spring_preload': 0.5 * reference['pilot_spring_preload'],
        'damping_orifice_diameter': 0.8 * reference['damping_orifice_diameter'],
    }


@pytest.mark.parametrize('design', ['reference', 'variant'])
@pytest.mark.parametrize('back_pressure', [0.5 * BAR, 5 * BAR, 30 * BAR])
def test_back_pressure_raises_the_cracking_pressure_one_to_one(
    request, design, back_pressure
):
    """
    docs/model.md: every tank-facing area balances, so p_cr(p_t) = p_cr(0) + p_t.

    Asserted against the solver's cracking point at the back pressure, for a design
    the parameters were not fitted to as well.
    """
    params = request.getfixturevalue(design)
    at_ambient = cracking_pressure(params)
    assert cracking_pressure(params, tank_pressure=back_pressure) == pytest.approx(
        at_ambient + back_pressure, rel=1e-9
    )


@pytest.mark.parametrize('flow', [2 * LITRE_PER_MINUTE, 20 * LITRE_PER_MINUTE])
def test_a_steady_state_at_back_pressure_is_the_one_at_ambient_raised_by_it(reference, flow):
    """Pressures shifted by p_t, positions unchanged: the solver does not assume this."""
    back_pressure = 8 * BAR
    at_ambient = steady_state(reference, flow)
    raised = steady_state(reference, flow, tank_pressure=back_pressure)
    shift = np.zeros(8)
    shift[P_S:P_C + 1] = back_pressure
    np.testing.assert_allclose(raised, at_ambient + shift, rtol=1e-7, atol=1e-12)


@pytest.mark.parametrize(
    'tank_pressure, reason',
    [
        (np.nan, 'finite'),
        (np.inf, 'finite'),
        (-2e6, 'below'),
        (35.0e6, 'burst_pressure'),
    ],
)
def test_the_solver_refuses_a_tank_pressure_that_is_not_an_input(
    reference, tank_pressure, reason
):
    with pytest.raises(SteadyStateError, match=reason):
        steady_state(reference, 5 * LITRE_PER_MINUTE, tank_pressure=tank_pressure)


def test_a_tank_profile_beyond_the_limits_is_refused_before_the_run(reference):
    with pytest.raises(ParameterError, match='tank pressure schedule'):
        simulate(
            reference, FlowStep(end_time=0.01), STEP, STEP,
            tank=TankPressure(0.0, 40e6, step_time=0.005),
        )


def test_the_tank_at_ambient_leaves_the_figure_5_run_bit_identical(reference):
    """
    The paper's step with the tank at ambient, held (one number) or as a per-step profile.

    Both paths give the default run's states bit for bit, so Figure 5's measures stay
    byte-identical; the comparison with the code before issue 30 (the behaviour
    snapshot of both trees) is in notes/issue-30.md.
    """
    default = simulate(reference, REFERENCE_FLOW_STEP)
    held = simulate(reference, REFERENCE_FLOW_STEP, tank=TankPressure(0.0))
    flows = step_flows(REFERENCE_FLOW_STEP, STEP)
    profile = run_flows(
        reference, flows, STEP, initial_flow=REFERENCE_FLOW_STEP.initial_flow,
        tank_pressures=np.zeros(len(flows)),
    )
    for run in (held, profile):
        assert np.array_equal(run.states, default.states)
    assert np.array_equal(profile.tank_pressure, np.zeros(len(profile.time)))


def valve_sim(*args):
    result = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', *args],
        capture_output=True, text=True, timeout=300,
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_a_run_at_back_pressure_recorded_and_analysed_measures_as_at_ambient(tmp_path):
    """
    The chain simulate --tank-pressure -> bag -> analyse at a constant 5 bar tank.

    The run's measures are those at ambient (p_s shifted, docs/model.md); the bag
    holds the tank and relief flow, and analyse measures the supply above the tank,
    says so, and reports the relief flow.
    """
    bag = tmp_path / 'back_pressure.mcap'
    ambient = json.loads(valve_sim('simulate', '--json'))
    direct = json.loads(
        valve_sim('simulate', '--tank-pressure', '5e5', '--json', '--mcap', str(bag))
    )
    for name in ('P_o_percent', 'P_1_percent', 'T_1_ms', 'r_d', 'T_d_ms', 'T_s_ms'):
        assert direct[name] == pytest.approx(ambient[name], rel=1e-9), name
    (step,) = json.loads(valve_sim('analyse', str(bag), '--json'))['steps']
    assert step['details']['pressure'] == 'supply above the tank'
    assert step['details']['tank_pressure_pa'] == pytest.approx(5e5)
    assert step['T_1_ms'] == pytest.approx(direct['T_1_ms'], abs=0.2)  # 1 kHz bag
    for name in ('P_o_percent', 'P_1_percent', 'r_d', 'T_d_ms', 'T_s_ms'):
        assert step[name] == pytest.approx(direct[name], rel=0.02), name
    assert 'relief (to the tank) 5 / 20' in valve_sim('analyse', str(bag))
