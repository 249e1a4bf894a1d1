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

"""The study fast path: the lanes kernel and simulate_batch against the single-run kernel."""

import numpy as np
import pytest
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP
from valve_sim.analysis.steps.measures import MEASURE_NAMES, step_measures
from valve_sim.core.batch import simulate_batch
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import IntegrationError, SteadyStateError
from valve_sim.core.faults import FaultSet, HEALTHY
from valve_sim.core.integrator import advance, STEP_RATE_LIMIT
from valve_sim.core.lanes import advance_lanes
from valve_sim.core.model import fastest_chamber_rate, P_C, P_S
from valve_sim.core.parameters import scaled
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, simulate
from valve_sim.core.steady_state import steady_state, with_preset_pressure


def test_lanes_give_exactly_the_single_run_kernel(reference):
    """
    Each lane is bit-identical to advance() alone; a diverging lane leaves the others.

    The 3 MPa valve at 25 L/min needs split steps (test_model): that lane takes them
    alone while the others run on together; so does a valve with faults (friction and
    a leaking seat), whose terms the vectorised step leaves out. 18 valves: more than
    one group of LANES.
    """
    faults = FaultSet(
        bearing_coulomb_friction=5.0, bearing_static_friction=8.0, seat_leakage_diameter=2e-4
    )
    variants = [
        (reference, HEALTHY),
        (with_preset_pressure(reference, 3e6), HEALTHY),
        (reference, faults),
    ] + [(scaled(reference, {'d_c': change}), HEALTHY) for change in np.linspace(-8, 8, 15)]
    flows = np.concatenate([np.full(300, 5.0), np.full(4700, 25.0)]) * LITRE_PER_MINUTE
    starts = [steady_state(p, 5 * LITRE_PER_MINUTE) for p, _ in variants]
    coefficient_sets = [coefficients(p, f) for p, f in variants]
    alone = []
    for c, start in zip(coefficient_sets, starts):
        state = start.copy()
        alone.append((advance(state, flows, c, 1e-5, record_every=7), state))
    # One more valve, with a massless poppet, diverges at once. (An absurdly stiff supply
    # chamber, the example before, integrates now: the stiff step, test_stiff_chambers.)
    broken = coefficients(reference)._replace(pilot_poppet_mass=0.0)
    states = np.array(starts + [starts[0]])
    records, errors = advance_lanes(
        states, flows, coefficient_sets + [broken], 1e-5, record_every=7
    )
    c = coefficient_sets[1]
    assert max(1e-5 * fastest_chamber_rate(s, c) for s in records[1]) > STEP_RATE_LIMIT
    assert not np.array_equal(records[2], records[0])  # the faults act
    for lane, (record, final) in enumerate(alone):
        assert errors[lane] is None
        assert np.array_equal(records[lane], record)
        assert np.array_equal(states[lane], final)
    assert isinstance(errors[-1], IntegrationError) and 'diverged' in str(errors[-1])
    assert np.array_equal(states[-1], starts[0])  # a diverged lane is left as it was


def _measures(waveforms, scenario):
    return step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        scenario.step_time,
    ).values


def test_batch_skips_the_steady_lead_without_changing_the_measures(reference):
    """
    simulate_batch against simulate() on the paper's step.

    Stable starts (lead held, not integrated): the same samples, states within
    rounding, measures equal to 1e-9. An unstable start (d_c +60 %: its pilot mode
    grows at 5 L/min) is integrated as simulate() does it: bit-identical.
    """
    scenario = FlowStep(end_time=0.45)  # the paper's step, shorter (the window is truncated)
    variants = [reference, scaled(reference, {'m_m': 20}), scaled(reference, {'d_c': 60})]
    batch = [result.waveforms for result in simulate_batch(variants, scenario, lanes=2)]
    for params, fast in zip(variants, batch):
        full = simulate(params, scenario)
        assert np.array_equal(fast.time, full.time)
        assert np.array_equal(fast.inlet_flow, full.inlet_flow)
        pressure = np.abs(fast.states[:, P_S:P_C + 1] - full.states[:, P_S:P_C + 1])
        assert np.max(pressure) < 1e-12 * np.max(full.states[:, P_S])
        a, b = _measures(full, scenario), _measures(fast, scenario)
        for name in MEASURE_NAMES:
            assert (a[name] is None) == (b[name] is None), name
            if a[name] is not None:
                assert b[name] == pytest.approx(a[name], rel=1e-9, abs=1e-12), name
    assert np.array_equal(batch[2].states, simulate(variants[2], scenario).states)


def test_batch_reports_each_failure_in_its_place(reference):
    """
    Each run's RunResult (as scipy's OdeResult): the waveforms, or None and the reason.

    A run that diverges has its IntegrationError (time on the run's axis) as the reason,
    a start without a steady state its SteadyStateError; the rest run on.
    """
    scenario = FlowStep(end_time=0.3)
    # burst_pressure below the step's first peak (7.23 MPa): an overpressure after the step.
    # (V_p / 1000, the stiff valve used here before issue 40, now integrates in split steps.)
    stiff = dict(reference, burst_pressure=7.1e6)
    results = simulate_batch([reference, stiff, reference], scenario)
    assert not results[1].success and results[1].waveforms is None
    assert isinstance(results[1].error, IntegrationError)
    assert 'at t = 0.25' in results[1].message  # just after the step, not at 0
    assert results[1].message == str(results[1].error)
    (alone,) = simulate_batch([reference], scenario)
    assert alone.success and alone.error is None and alone.message == ''
    for result in (results[0], results[2]):
        assert result.success
        assert np.array_equal(result.waveforms.states, alone.waveforms.states)
    (nan_start,) = simulate_batch([reference], FlowStep(initial_flow=float('nan')))
    assert not nan_start.success and nan_start.waveforms is None
    assert isinstance(nan_start.error, SteadyStateError) and nan_start.message


def test_paper_scenario_measures_through_the_batch(reference):
    """The reference valve's measures through simulate_batch equal simulate()'s (1e-9)."""
    fast = simulate_batch([reference], REFERENCE_FLOW_STEP)[0].waveforms
    full = simulate(reference, REFERENCE_FLOW_STEP)
    a, b = _measures(full, REFERENCE_FLOW_STEP), _measures(fast, REFERENCE_FLOW_STEP)
    for name in MEASURE_NAMES:
        assert b[name] == pytest.approx(a[name], rel=1e-9), name
