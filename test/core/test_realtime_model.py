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

"""RealTimeModel: stepping in whole steps, catch-up limit, trial, roll-back, update outcomes."""

import numpy as np
import pytest
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import IntegrationError, OverpressureError, ParameterError
from valve_sim.core.integrator import advance
from valve_sim.core.model import P_S
from valve_sim.core.parameters import load_parameters
from valve_sim.core.realtime_model import RealTimeModel, Status, step_ns, TRIAL_STEPS
from valve_sim.core.simulation import LITRE_PER_MINUTE
from valve_sim.core.steady_state import steady_state


FLOW = 5.0 * LITRE_PER_MINUTE
START_NS = 1_000_000_000_000  # any clock time; the model time is anchored to it


@pytest.fixture(scope='module')
def reference():
    return load_parameters().params


@pytest.fixture
def model(reference):
    model = RealTimeModel(reference, 1e-5, FLOW)
    model.start(START_NS)
    return model


def test_starts_at_the_exact_steady_state(model, reference):
    assert np.array_equal(model.state, steady_state(reference, FLOW))
    assert RealTimeModel(reference, 1e-5, 0.0).state.tolist() == [0.0] * 8


def test_runs_from_the_closed_valve(reference):
    model = RealTimeModel(reference, 1e-5, 0.0)
    model.start(START_NS)
    model.advance_to(START_NS + 300_000_000, FLOW, max_lag_ns=10**9)
    assert np.all(np.isfinite(model.state)) and model.state[P_S] > 0.0


def test_model_time_follows_an_irregular_clock_without_drift(model, reference):
    """Clock ticks of 1.000123 ms: whole 10 us steps, remainder carried, same result as one run."""
    offline = steady_state(reference, FLOW)
    now_ns, steps = START_NS, 0
    for _ in range(500):
        now_ns += 1_000_123
        steps += model.advance_to(now_ns, 2 * FLOW, max_lag_ns=10**9).steps
        assert 0 <= now_ns - model.time_ns < 10_000
    assert steps == (now_ns - START_NS) // 10_000
    assert model.time_ns == START_NS + steps * 10_000
    advance(offline, np.full(steps, 2 * FLOW), coefficients(reference), 1e-5)
    assert np.array_equal(model.state, offline), (
        'chunked stepping equals one offline run, bit for bit'
    )


def test_lag_beyond_the_catch_up_limit_is_skipped(model):
    progress = model.advance_to(START_NS + 1_000_000_000, FLOW, max_lag_ns=50_000_000)
    assert progress.skipped_ns == 950_000_000
    assert progress.steps == 5000
    assert model.time_ns == START_NS + 1_000_000_000


def test_divergence_leaves_state_and_model_time_unchanged(model):
    state = model.state.copy()
    with pytest.raises(IntegrationError):
        model.advance_to(START_NS + 100_000_000, 1.0, max_lag_ns=10**9)  # 60 000 L/min
    assert np.array_equal(model.state, state)
    assert model.time_ns == START_NS
    model.hold_until(START_NS + 1_234_567)
    assert model.time_ns == START_NS + 1_230_000 and np.array_equal(model.state, state)


def test_trial_refuses_a_diverging_change_without_touching_the_model(model, reference):
    state = model.state.copy()
    model.trial(reference, 1e-5, FLOW)
    # A 0.1 g main valve on a 1 mm^3 pilot chamber of stiff water rings beyond the
    # sub-steps allowed at 100 us (test_integrability.py): refused before it is tried.
    corner = {'main_valve_mass': 1e-4, 'main_valve_damping': 1e4, 'pilot_volume': 1e-9,
              'bulk_modulus': 1e10}
    with pytest.raises(ParameterError, match='cannot be integrated'):
        model.trial({**reference, **corner}, 1e-4, FLOW)
    assert np.array_equal(model.state, state) and model.step_size == 1e-5


def test_roll_back_returns_to_the_parameters_before_the_last_change(model, reference):
    assert not model.roll_back(START_NS), 'nothing to roll back to before any change'
    heavier = {**reference, 'main_valve_mass': reference['main_valve_mass'] * 2}
    model.retune(heavier, 2e-5)
    assert (model.params, model.step_size) == (heavier, 2e-5)
    assert model.roll_back(START_NS + 20_000)
    assert (model.params, model.step_size) == (reference, 1e-5)
    assert not model.roll_back(START_NS + 20_000), 'one level only'


def test_roll_back_undoes_only_a_change_within_the_trial_window(model, reference):
    """A failure after the trial window of a change was not caused by it: the change stays."""
    preset_moved = {**reference, 'pilot_spring_preload': reference['pilot_spring_preload'] * 1.1}
    model.retune(preset_moved, 1e-5)
    window_ns = TRIAL_STEPS * 10_000
    model.advance_to(START_NS + 3 * window_ns, FLOW, max_lag_ns=10**10)
    assert not model.roll_back(START_NS + 3 * window_ns), 'an unrelated, later failure'
    assert model.params == preset_moved
    model.retune(reference, 1e-5)
    assert model.roll_back(model.time_ns + window_ns // 2), 'a failure within the window'
    assert model.params == preset_moved


def test_a_retune_that_changes_nothing_leaves_the_change_before_it_to_roll_back(
    model, reference
):
    """A sensor or publish-rate change retunes with the model unchanged: not a cause."""
    heavier = {**reference, 'main_valve_mass': reference['main_valve_mass'] * 2}
    model.retune(heavier, 1e-5)
    model.advance_to(START_NS + 100_000, FLOW, max_lag_ns=10**9)
    model.retune(dict(heavier), 1e-5)  # equal values, later
    assert model.roll_back(START_NS + 150_000)
    assert model.params == reference


def test_a_halted_model_holds_its_state_until_resumed(model):
    state = model.state.copy()
    model.halt('overpressure')
    assert model.advance_to(START_NS + 5_000_000, 4 * FLOW, max_lag_ns=10**9).steps == 0
    assert np.array_equal(model.state, state) and model.time_ns == START_NS + 5_000_000
    model.resume()
    assert model.advance_to(START_NS + 6_000_000, 4 * FLOW, max_lag_ns=10**9).steps == 100
    model.halt('overpressure')
    model.reset(FLOW)
    assert model.halted is None, 'a reset resumes'


def test_failure_reports_the_model_time_of_the_failing_step(model, reference):
    with pytest.raises(OverpressureError) as failure:
        model.advance_to(START_NS + 100_000_000, 1.0, max_lag_ns=10**9)  # 60 000 L/min
    assert START_NS < failure.value.failure_ns <= START_NS + 100_000_000
    assert failure.value.failure_ns % 10_000 == 0


def test_reset_at_a_tiny_flow_installs_a_state_that_holds(reference):
    model = RealTimeModel(reference, 1e-5, 0.0)
    model.start(START_NS)
    model.reset(1.67e-14)  # 1e-9 L/min
    state = model.state.copy()
    model.advance_to(START_NS + 100_000_000, 1.67e-14, max_lag_ns=10**9)
    assert model.state[P_S] == pytest.approx(state[P_S], rel=1e-9)
    assert np.max(np.abs(model.state[:4] - state[:4])) < 1.0  # [Pa]


def test_reset_goes_to_the_steady_state_of_the_given_flow(model, reference):
    model.advance_to(START_NS + 10_000_000, 4 * FLOW, max_lag_ns=10**9)
    model.reset(4 * FLOW)
    assert model.state[P_S] == steady_state(reference, 4 * FLOW)[P_S]


def test_step_size_is_kept_on_a_nanosecond_grid():
    assert step_ns(1e-5) == 10_000 and step_ns(1e-7) == 100 and step_ns(1e-12) == 1


# update(): the failure policy, one test per Outcome.
DIVERGING_FLOW = 1.0  # [m^3/s] 60 000 L/min: p_s passes burst_pressure within milliseconds


def test_update_reports_progress_and_skipped_lag(model):
    outcome = model.update(START_NS + 1_000_000_000, FLOW, max_lag_ns=50_000_000)
    assert outcome.status is Status.PROGRESS and outcome.error is None
    assert (outcome.steps, outcome.skipped_ns) == (5000, 950_000_000)
    assert not outcome.rolled_back and model.halted is None


def test_update_after_a_failure_without_a_recent_change_halts_and_holds(model, reference):
    state = model.state.copy()
    outcome = model.update(START_NS + 100_000_000, DIVERGING_FLOW, max_lag_ns=10**9)
    assert outcome.status is Status.FAILURE and outcome.overpressure
    assert not outcome.rolled_back and model.params == reference
    assert model.halted == str(outcome.error)
    assert np.array_equal(model.state, state) and model.time_ns == START_NS + 100_000_000
    assert model.saturated == reference['burst_pressure'], 'p_s is read at the limit it passed'
    assert model.output_state()[P_S] == reference['burst_pressure']
    assert model.output_state()[1:].tolist() == state[1:].tolist()


def test_update_of_a_halted_model_only_holds_until_resumed(model):
    model.update(START_NS + 100_000_000, DIVERGING_FLOW, max_lag_ns=10**9)
    state = model.state.copy()
    outcome = model.update(START_NS + 200_000_000, FLOW, max_lag_ns=10**9)
    assert outcome.status is Status.HALTED and outcome.error is None and outcome.steps == 0
    assert np.array_equal(model.state, state) and model.time_ns == START_NS + 200_000_000
    assert model.resume(), 'it was halted'
    assert model.saturated is None and np.array_equal(model.output_state(), model.state)
    assert not model.resume(), 'it runs'
    assert model.update(START_NS + 201_000_000, FLOW, max_lag_ns=10**9).steps == 100


def test_update_rolls_back_a_change_that_can_have_caused_the_failure(model, reference):
    """A change within the trial window is undone, and the model goes on with the old one."""
    tighter = {**reference, 'burst_pressure': model.state[P_S] * 1.01}
    model.retune(tighter, 1e-5)
    outcome = model.update(START_NS + 10_000_000, 4 * FLOW, max_lag_ns=10**9)
    assert outcome.status is Status.ROLLED_BACK and outcome.rolled_back and outcome.overpressure
    assert model.params == reference and model.halted is None and model.saturated is None
    assert model.update(START_NS + 20_000_000, 4 * FLOW, max_lag_ns=10**9).status is (
        Status.PROGRESS
    )


def test_update_halts_after_a_roll_back_whose_parameters_refuse_the_input(model, reference):
    """Rolled back to a max_inlet_flow below the inlet flow: the model cannot run on."""
    model.retune({**reference, 'max_inlet_flow': 10.0}, 1e-5)
    outcome = model.update(START_NS + 100_000_000, DIVERGING_FLOW, max_lag_ns=10**9)
    assert DIVERGING_FLOW > reference['max_inlet_flow']
    assert outcome.status is Status.FAILURE and outcome.rolled_back
    assert model.params == reference and model.halted == str(outcome.error)


def test_update_tells_a_divergence_from_an_overpressure(reference):
    """A valve the step cannot integrate (retuned without its trial): a divergence."""
    model = RealTimeModel(reference, 1e-5, FLOW)
    model.start(START_NS)
    model.retune({**reference, 'intermediate_volume': 1e-9}, 1e-5)  # retune: no trial
    model._previous = None  # the node would have refused it: here nothing to roll back to
    # ... it integrates (the stiff step); a massless poppet cannot.
    model._coefficients = model._coefficients._replace(pilot_poppet_mass=0.0)
    outcome = model.update(START_NS + 100_000_000, reference['max_inlet_flow'], 10**9)
    assert outcome.status is Status.FAILURE and not outcome.overpressure
    assert isinstance(outcome.error, IntegrationError)
    assert model.saturated is None and np.array_equal(model.output_state(), model.state)
