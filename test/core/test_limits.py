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

"""Physical limits: absurd flows and states refused, tiny flows ordinary, overpressure apart."""

import json
import subprocess
import sys

import numpy as np
import pytest
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import (
    IntegrationError,
    OverpressureError,
    ParameterError,
    SteadyStateError,
)
from valve_sim.core.integrator import advance, crossing_is_accurate, splits_needed
from valve_sim.core.lanes import advance_lanes
from valve_sim.core.model import P_S, Y
from valve_sim.core.parameters import load_parameters, validate
from valve_sim.core.retuning import check_limits
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, simulate
from valve_sim.core.steady_state import steady_state


FLOW = 5.0 * LITRE_PER_MINUTE


@pytest.fixture(scope='module')
def reference():
    return load_parameters().params


@pytest.mark.parametrize('flow', [1.0, 0.05])
def test_steady_state_refuses_a_flow_beyond_max_inlet_flow(reference, flow):
    with pytest.raises(SteadyStateError, match='exceeds max_inlet_flow'):
        steady_state(reference, flow)


@pytest.mark.parametrize('flow', [1.0, 0.05])
def test_steady_state_beyond_burst_pressure_is_refused_as_an_overpressure(reference, flow):
    """With max_inlet_flow lifted out of the way (its range allows 10 m^3/s)."""
    generous = validate({**reference, 'max_inlet_flow': 2 * flow})
    with pytest.raises(SteadyStateError, match='overpressure: supply_pressure .* burst_pressure'):
        steady_state(generous, flow)
    full_stroke = steady_state(reference, reference['max_inlet_flow'])
    assert full_stroke[P_S] < reference['burst_pressure'], 'the largest valid flow is relieved'


@pytest.mark.parametrize('flow', [1e-15, 1e-12, 1e-9])
def test_tiny_flows_fill_the_closed_valve_without_divergence(reference, flow):
    """2 s from the empty valve: all four chambers fill together, as the compressibility says."""
    state = np.zeros(8)
    advance(state, np.full(200_000, flow), coefficients(reference), 1e-5)
    chambers = ('supply_volume', 'intermediate_volume', 'pilot_volume', 'poppet_chamber_volume')
    volume = sum(reference[name] for name in chambers)
    expected = reference['bulk_modulus'] * flow * 2.0 / volume
    assert state[P_S] == pytest.approx(expected, rel=1e-3)
    assert np.allclose(state[:4], state[P_S], rtol=1e-3), state
    assert not state[4:].any(), 'both valves stay seated and still'


@pytest.mark.parametrize('flow', [1e-15, 1.67e-14, 1e-13])
def test_steady_state_at_a_tiny_flow_holds_the_pilot_at_its_opening(reference, flow):
    state = steady_state(reference, flow)
    resolvable = steady_state(reference, 1e-12)
    assert state[P_S] == pytest.approx(resolvable[P_S], rel=1e-8)
    assert state[Y] == pytest.approx(resolvable[Y] * flow / 1e-12, rel=1e-3)
    advance(state, np.full(10_000, flow), coefficients(reference), 1e-5)
    assert state[P_S] == pytest.approx(resolvable[P_S], rel=1e-8), 'it is a steady state'


def test_the_closed_valve_steps_are_split_the_running_valves_are_not(reference):
    c = coefficients(reference)
    assert splits_needed(np.zeros(8), c, 1e-5) > 1
    assert splits_needed(steady_state(reference, FLOW), c, 1e-5) == 1


def test_overpressure_is_reported_apart_from_divergence(reference):
    generous = {**reference, 'max_inlet_flow': 0.1}
    state = steady_state(generous, FLOW)
    before = state.copy()
    with pytest.raises(OverpressureError, match='burst_pressure'):
        advance(state, np.full(2000, 0.05), coefficients(generous), 1e-5)
    assert np.array_equal(state, before)
    flood = np.full(10, 0.05)
    assert crossing_is_accurate(state, flood, 0, coefficients(generous), 1e-5), 'physics'
    # A massless poppet (no valve the catalogue accepts) gives non-finite accelerations:
    # a divergence, never an overpressure. (A 1 mm^3 intermediate chamber at 100 L/min,
    # the example before the stiff step, now integrates: test_stiff_chambers.py.)
    massless = coefficients(generous)._replace(pilot_poppet_mass=0.0)
    with pytest.raises(IntegrationError, match='diverged') as failure:
        advance(state, np.full(20, 100 * LITRE_PER_MINUTE), massless, 1e-5)
    assert not isinstance(failure.value, OverpressureError)


def test_a_change_that_would_leave_the_limits_is_refused(reference):
    state = steady_state(reference, FLOW)
    check_limits(reference, state, FLOW)
    with pytest.raises(ParameterError, match='max_inlet_flow'):
        check_limits({**reference, 'max_inlet_flow': FLOW / 2}, state, FLOW)
    with pytest.raises(ParameterError, match='current state .* burst_pressure'):
        check_limits({**reference, 'burst_pressure': 5e6}, state, FLOW)
    with pytest.raises(ParameterError, match='would crack at .* burst_pressure'):
        check_limits({**reference, 'burst_pressure': 5e6}, np.zeros(8), 0.0)


def test_an_offline_schedule_beyond_max_inlet_flow_is_refused(reference):
    with pytest.raises(ParameterError, match='inlet flow schedule: .* exceeds max_inlet_flow'):
        simulate(reference, FlowStep(final_flow=200 * LITRE_PER_MINUTE))


def test_lanes_split_the_same_steps_as_one_valve_alone(reference):
    """advance_lanes stays bit-identical to advance where a lane's steps are split."""
    flows = np.full(3000, 1e-9)
    flows[1500:] = FLOW
    starts = np.array([np.zeros(8), steady_state(reference, FLOW)])
    c = coefficients(reference)
    records, errors = advance_lanes(starts.copy(), flows, [c, c], 1e-5, record_every=100)
    assert errors == [None, None]
    for lane, start in enumerate(starts):
        alone = advance(start.copy(), flows, c, 1e-5, record_every=100)
        assert np.array_equal(records[lane], alone)


def test_simulate_reports_an_overpressure_as_valve_node_publishes_it(reference, tmp_path):
    """1 m^3/s into the valve: the run halts, p_s at burst_pressure from then on, exit 1."""
    csv_path = tmp_path / 'run.csv'
    done = subprocess.run(
        [sys.executable, '-m', 'valve_sim.commands.cli', 'simulate', '--set',
         'max_inlet_flow=10.0', '--final-flow', '1', '--csv', str(csv_path), '--json'],
        capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 1 and 'OVERPRESSURE at t = ' in done.stderr, done.stderr
    assert 'Traceback' not in done.stderr
    measures = json.loads(done.stdout)
    assert all(measures[name] is None for name in measures['reasons'])
    tripped = measures['details']['overpressure']['t']
    rows = np.loadtxt(csv_path, delimiter=',', skiprows=1)
    after = rows[rows[:, 0] >= tripped]
    assert np.all(after[:, 2] == reference['burst_pressure'])  # p_s: the limit it passed
    assert np.all(after[:, 3:] == after[0, 3:])  # the rest: the last good state, held
    assert np.all(rows[rows[:, 0] < tripped, 2] < reference['burst_pressure'])
