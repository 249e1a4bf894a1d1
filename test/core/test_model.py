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

"""Physics of the model core: balances, conservation, convergence, seats, divergence."""

import numpy as np
import pytest
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import IntegrationError, SteadyStateError
from valve_sim.core.integrator import advance, STEP_RATE_LIMIT
from valve_sim.core.model import (
    fastest_chamber_rate,
    flows,
    net_forces,
    P_C,
    P_M,
    P_P,
    P_S,
    state_derivative,
    X,
    X_DOT,
    Y,
    Y_DOT,
)
from valve_sim.core.parameters import load_parameters, validate
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, simulate
from valve_sim.core.steady_state import (
    cracking_pressure,
    preload_for_cracking_pressure,
    steady_state,
    with_preset_pressure,
)


FLOWS_LPM = (0.3, 2.0, 5.0, 20.0, 35.0)
# (d_c [m], k_p [N/m]) of valves in `valve-sim sensitivity`'s default design (+-20 %,
# N = 256, seed 0) whose preset solve once failed: hybr sat on the cracking point
# (residual ~1e-16) but reported "not making good progress". The first four failed on
# the geometry before its re-derivation in issue 12, the others would on today's; the
# masses and volumes the design also varies do not enter the steady state.
HYBR_NO_PROGRESS = (
    (0.0009698319058865309, 170687.97699064016),
    (0.0010349987853318454, 147398.7608127296),
    (0.001026642469316721, 145962.67995387316),
    (0.0009466181144118309, 168069.90592852235),
    (0.0008317104239016772, 165104.5354641974),
    (0.0010479842707514764, 154655.97245320678),
    (0.0010205121580511333, 165504.45680841804),
    (0.0010453490290790797, 152880.10879680514),
    (0.0008439079605042935, 188949.26483109593),
    (0.001053871638327837, 160759.02764722705),
    (0.0009798686228692532, 167662.3238325119),
    (0.0010651162497699262, 160707.84964859486),
)


@pytest.fixture(scope='module')
def params():
    return load_parameters().params


@pytest.mark.parametrize('flow_lpm', FLOWS_LPM)
def test_steady_state_balances_flows_and_forces(params, flow_lpm):
    q_in = flow_lpm * LITRE_PER_MINUTE
    state = steady_state(params, q_in)
    c = coefficients(params)
    q_m1, q_m2, q_n, q_c, q_s, q_p = flows(state, c)
    scale = q_in
    assert q_m1 == pytest.approx(q_m2, abs=1e-9 * scale)  # intermediate chamber
    assert q_n == pytest.approx(q_c, abs=1e-9 * scale)  # pilot chamber
    assert q_c + q_s == pytest.approx(q_p, abs=1e-9 * scale)  # poppet chamber
    assert q_m1 + q_n + q_s == pytest.approx(q_in, abs=1e-9 * scale)  # supply chamber
    assert q_m2 + q_p == pytest.approx(q_in, rel=1e-9)  # all inflow leaves to the tank
    force_x, force_y = net_forces(state, c)
    force_scale = c.back_area * state[P_S]
    assert state[Y] > 0.0 and abs(force_y) < 1e-9 * force_scale
    if state[X] > 0.0:
        assert abs(force_x) < 1e-9 * force_scale
    else:
        assert force_x <= 1e-9 * force_scale  # a seated main valve is pushed onto its seat
    assert state[X_DOT] == 0.0 and state[Y_DOT] == 0.0


def test_small_flow_passes_through_the_pilot_only(params):
    state = steady_state(params, 0.3 * LITRE_PER_MINUTE)
    assert state[X] == 0.0 and state[Y] > 0.0
    assert state[P_M] == pytest.approx(state[P_S], rel=1e-9)


def test_zero_flow_is_the_empty_closed_valve(params):
    assert np.all(steady_state(params, 0.0) == 0.0)


@pytest.mark.parametrize('flow_lpm', (5.0, 20.0))
def test_steady_state_is_exact_no_start_up_transient(params, flow_lpm):
    q_in = flow_lpm * LITRE_PER_MINUTE
    start = steady_state(params, q_in)
    state = start.copy()
    record = advance(state, np.full(20000, q_in), coefficients(params), 1e-5, record_every=100)
    pressures = record[:, P_S:P_C + 1]
    assert np.max(np.abs(pressures - start[P_S:P_C + 1])) < 1e-6 * start[P_S]
    assert np.max(np.abs(record[:, X] - start[X])) < 1e-6 * max(start[X], 1e-6)


def swept_areas(c, velocity):
    """Return the net area [m^2] by which a velocity (X_DOT, Y_DOT) takes chamber volume."""
    if velocity == X_DOT:
        return c.supply_force_area + c.intermediate_force_area - c.back_area
    return c.rod_area + c.poppet_chamber_area


def chamber_inflows(state, c, volumes, beta):
    """Net inflow of each chamber s, m, p, c [m^3/s] (V / beta dp/dt)."""
    return volumes / beta * state_derivative(state, 0.0, c)[P_S:P_C + 1]


@pytest.mark.parametrize('seed', range(6))
def test_each_chamber_sweeps_the_area_its_pressure_pushes_on(params, seed):
    """
    Swept area == force area, chamber by chamber, for the main valve and the poppet.

    dq_i/dv = -dF/dp_i for every chamber i and valve velocity v: the volume a valve's
    motion takes from a chamber is the area that chamber's pressure pushes it with, so
    the pressures' work on the valves is the work the chambers give up. Checked on the
    reference and on geometries varied at random (an unbalanced pilot poppet included),
    with the poppet on its seat (no flow force).
    """
    rng = np.random.default_rng(seed)
    varied = dict(params)
    if seed:
        for name in ('main_valve_back_diameter', 'first_throttle_inner_diameter',
                     'second_throttle_outer_diameter', 'sensing_rod_diameter',
                     'pilot_seat_diameter'):
            varied[name] *= rng.uniform(0.85, 1.15)
    c = coefficients(validate(varied))
    volumes = np.array([varied[k] for k in ('supply_volume', 'intermediate_volume',
                                            'pilot_volume', 'poppet_chamber_volume')])
    beta = varied['bulk_modulus']
    state = np.array([7e6, 5e6, 3e6, 2e6, 1e-4, 0.0, 0.0, 0.0])
    for velocity, force in ((X_DOT, 0), (Y_DOT, 1)):
        moving = state.copy()
        moving[velocity] = 1e-3
        swept = (chamber_inflows(moving, c, volumes, beta)
                 - chamber_inflows(state, c, volumes, beta)) / 1e-3
        for chamber in (P_S, P_M, P_P, P_C):
            pushed = state.copy()
            pushed[chamber] += 1e5
            area = (net_forces(pushed, c)[force] - net_forces(state, c)[force]) / 1e5
            assert swept[chamber] == pytest.approx(-area, rel=1e-9, abs=1e-15), (velocity, chamber)
    assert c.poppet_chamber_area == pytest.approx(
        np.pi / 4 * (varied['pilot_seat_diameter'] ** 2 - varied['sensing_rod_diameter'] ** 2))


def test_volume_conservation_identity(params):
    """
    Sum of V/beta dp/dt over the chambers equals inflow - outflow - net displacement.

    This holds at any state.
    """
    c = coefficients(params)
    rng = np.random.default_rng(1)
    volumes = np.array(
        [
            params['supply_volume'],
            params['intermediate_volume'],
            params['pilot_volume'],
            params['poppet_chamber_volume'],
        ]
    )
    for _ in range(50):
        state = np.array(
            [
                rng.uniform(0, 9e6),
                rng.uniform(0, 9e6),
                rng.uniform(0, 9e6),
                rng.uniform(0, 9e6),
                rng.uniform(0, 4e-4),
                rng.uniform(-0.1, 0.1),
                rng.uniform(0, 3e-4),
                rng.uniform(-0.1, 0.1),
            ]
        )
        q_in = rng.uniform(0, 6e-4)
        rates = state_derivative(state, q_in, c)
        stored = np.sum(volumes / params['bulk_modulus'] * rates[P_S:P_C + 1])
        _, q_m2, _, _, _, q_p = flows(state, c)
        displaced = swept_areas(c, X_DOT) * state[X_DOT] + swept_areas(c, Y_DOT) * state[Y_DOT]
        assert stored == pytest.approx(q_in - q_m2 - q_p - displaced, rel=1e-9, abs=1e-15)


def test_volume_is_conserved_over_a_step_response(params):
    """Integrated over the paper's step: fluid stored = fluid in - fluid out - displaced volume."""
    c = coefficients(params)
    step = 1e-6
    flows_in = np.full(30000, 20 * LITRE_PER_MINUTE)
    state = steady_state(params, 5 * LITRE_PER_MINUTE)
    start = state.copy()
    record = advance(state, flows_in, c, step, record_every=1)
    states = np.vstack([start, record])
    outflow = np.array([sum(flows(s, c)[i] for i in (1, 5)) for s in states])
    out_volume = np.sum((outflow[1:] + outflow[:-1]) / 2) * step  # trapezoidal rule
    volumes = np.array(
        [
            params[k]
            for k in (
                'supply_volume',
                'intermediate_volume',
                'pilot_volume',
                'poppet_chamber_volume',
            )
        ]
    )
    stored = np.sum(
        volumes / params['bulk_modulus'] * (state[P_S:P_C + 1] - start[P_S:P_C + 1])
    )
    displaced = swept_areas(c, X_DOT) * (state[X] - start[X]) + swept_areas(c, Y_DOT) * (
        state[Y] - start[Y]
    )
    inflow = flows_in.sum() * step
    assert stored == pytest.approx(inflow - out_volume - displaced, rel=1e-4)


def test_rk4_converges_with_fourth_order(params):
    """Errors against a 1.25 us solution shrink ~16x per halving of the step (order 4)."""
    c = coefficients(params)
    start = steady_state(params, 5 * LITRE_PER_MINUTE)

    def end_state(step):
        state = start.copy()
        advance(state, np.full(int(round(0.01 / step)), 20 * LITRE_PER_MINUTE), c, step)
        return state

    reference = end_state(1.25e-6)
    scale = np.array([1e6] * 4 + [1e-4, 1e-2, 1e-5, 1e-2])
    errors = [np.max(np.abs(end_state(h) - reference) / scale) for h in (1e-5, 5e-6, 2.5e-6)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[0] < 1e-3
    assert np.all(orders > 3.5), orders


def test_measures_agree_across_step_sizes(params):
    from valve_sim.analysis.steps.measures import step_measures

    results = []
    for step in (2e-6, 5e-6, 1e-5):
        w = simulate(params, FlowStep(), step, 1e-4)
        results.append(
            step_measures(w.time, w['supply_pressure'], w['main_valve_displacement'], 0.25).values
        )
    for name in results[0]:
        assert results[2][name] == pytest.approx(results[0][name], rel=2e-3), name


def test_closed_valve_start_cracks_and_settles_near_the_preset(params):
    """0 -> 20 L/min from the empty valve: pilot cracks, then the main valve, no NaN, settles."""
    w = simulate(
        params,
        FlowStep(initial_flow=0.0, final_flow=20 * LITRE_PER_MINUTE, step_time=0.01, end_time=1.2),
        1e-5,
        1e-4,
    )
    assert np.all(np.isfinite(w.states))
    p_s, x, y = w['supply_pressure'], w['main_valve_displacement'], w['poppet_displacement']
    assert np.all(x >= 0.0) and np.all(y >= 0.0)
    first_pilot = np.argmax(y > 0.0)
    first_main = np.argmax(x > 0.0)
    assert 0 < first_pilot < first_main
    final = steady_state(params, 20 * LITRE_PER_MINUTE)
    settled = w.time > 1.1
    assert np.mean(p_s[settled]) == pytest.approx(final[P_S], rel=2e-3)
    assert np.mean(x[settled]) == pytest.approx(final[X], rel=2e-2)
    assert np.max(p_s) < 1.5 * final[P_S]


def test_ramp_from_closed_valve_and_back_down(params):
    """
    Closed -> ramp to rated flow -> ramp back to zero.

    The valves reseat and nothing goes negative.
    """
    w = simulate(
        params,
        FlowStep(
            initial_flow=0.0,
            final_flow=20 * LITRE_PER_MINUTE,
            step_time=0.0,
            end_time=0.6,
            ramp_time=0.2,
        ),
        1e-5,
        1e-4,
    )
    state = w.states[-1].copy()
    c = coefficients(params)
    advance(state, np.linspace(20, 0, 30000) * LITRE_PER_MINUTE, c, 1e-5)
    advance(state, np.zeros(50000), c, 1e-5)
    assert np.all(np.isfinite(state))
    assert state[X] == 0.0  # the main valve is back on its seat
    assert 0.0 <= state[Y] < 1e-6  # the poppet closes asymptotically ...
    # With no flow every chamber is at p_s: the rod and the poppet chamber's net area,
    # A_s + A_c = A_v, carry the pilot spring's preload.
    pilot_cracking = (params['pilot_spring_stiffness'] * params['pilot_spring_preload']
                      / (c.rod_area + c.poppet_chamber_area))
    assert state[P_S] == pytest.approx(
        pilot_cracking, rel=1e-2
    )  # ... as p_s falls to its cracking pressure


def test_cracking_pressure_and_preset(params):
    crack = cracking_pressure(params)
    assert 0.0 < crack < steady_state(params, 5 * LITRE_PER_MINUTE)[P_S]
    tuned = dict(params, pilot_spring_preload=preload_for_cracking_pressure(params, 5e6))
    assert cracking_pressure(tuned) == pytest.approx(5e6, rel=1e-8)
    just_below = steady_state(tuned, 0.5 * LITRE_PER_MINUTE)
    assert just_below[X] == 0.0 and just_below[P_S] < 5e6


def test_the_preset_is_found_where_hybr_reports_no_progress(params):
    for d_c, k_p in HYBR_NO_PROGRESS:
        changes = {'damping_orifice_diameter': d_c, 'pilot_spring_stiffness': k_p}
        valve = validate({**params, **changes})
        preset = with_preset_pressure(valve, 7e6)
        assert cracking_pressure(preset) == pytest.approx(7e6, rel=1e-9), (d_c, k_p)


def test_a_valve_without_a_cracking_point_is_refused_with_its_reason(params):
    # d_c -50 %: the damping orifice cannot unload the main valve: the pressure rises
    # past the burst pressure before the main stage opens.
    narrow = validate({**params, 'damping_orifice_diameter': 0.5e-3})
    with pytest.raises(SteadyStateError, match='no cracking point found: the pilot-stage '
                       'balances have no solution'):
        cracking_pressure(narrow)
    with pytest.raises(SteadyStateError, match='no cracking point found'):
        with_preset_pressure(narrow, 7e6)
    assert steady_state(narrow, 1 * LITRE_PER_MINUTE)[X] == 0.0
    with pytest.raises(SteadyStateError, match='exceeds burst_pressure'):
        steady_state(narrow, 5 * LITRE_PER_MINUTE)
    # A main spring of 300 N/mm, 60x the soft one: the poppet reaches its stop before the
    # main valve lifts.
    stiff = validate({**params, 'main_spring_stiffness': 3e5})
    with pytest.raises(SteadyStateError, match='beyond its stroke y_max = 0.001 m: it reaches '
                       'its end stop before the main valve lifts off'):
        cracking_pressure(stiff)
    opened = steady_state(stiff, 5 * LITRE_PER_MINUTE)
    assert opened[X] > 0.0 and opened[Y] == params['poppet_stroke'] and opened[P_S] > 20e6


def test_divergence_is_reported_not_returned(params):
    # A massless poppet (no valve the catalogue accepts): advance() integrates what it is
    # given, and its non-finite accelerations are a divergence, raised, not returned.
    c = coefficients(params)._replace(pilot_poppet_mass=0.0)
    state = steady_state(params, 5 * LITRE_PER_MINUTE)
    before = state.copy()
    with pytest.raises(IntegrationError, match='diverged'):
        advance(state, np.full(20, 100 * LITRE_PER_MINUTE), c, 1e-5)
    assert np.array_equal(state, before)


def test_stiff_chamber_steps_are_split_and_agree_with_small_steps(params):
    # 3 MPa preset, 25 L/min: the chamber between the main throttles is too stiff for
    # one RK4 step of 10 us (it diverged before steps were split); 2.5 us needs no split.
    low = with_preset_pressure(params, 3e6)
    scenario = FlowStep(5 * LITRE_PER_MINUTE, 25 * LITRE_PER_MINUTE, 0.05, 0.3)
    split = simulate(low, scenario, 1e-5, 1e-3)
    small = simulate(low, scenario, 2.5e-6, 1e-3)
    scale = np.max(np.abs(small.states), axis=0) + 1e-12
    assert np.max(np.abs(split.states - small.states) / scale) < 1e-4
    c = coefficients(low)
    assert max(1e-5 * fastest_chamber_rate(state, c) for state in split.states) > STEP_RATE_LIMIT
