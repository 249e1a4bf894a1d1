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

"""valve_node's live parameter change planned once (core.retuning.plan_change) and applied once."""

import pytest
from valve_sim.core import retuning, steady_state
from valve_sim.core.parameters import load_parameters
from valve_sim.core.realtime_model import RealTimeModel
from valve_sim.core.retuning import plan_change
from valve_sim.core.sensors import SensorStage


@pytest.fixture
def loaded():
    return load_parameters()


@pytest.fixture
def model(loaded):
    return RealTimeModel(loaded.params, 1e-5, loaded.settings['initial_inlet_flow'])


@pytest.fixture
def solves(monkeypatch):
    """Count the cracking-point solves; Solves.solve is the uncounted solver."""
    calls = Solves()

    def counted(*args, **kwargs):
        calls.append(args)
        return calls.solve(*args, **kwargs)

    monkeypatch.setattr(steady_state, 'cracking_pressure', counted)
    monkeypatch.setattr(retuning, 'cracking_pressure', counted)
    return calls


class Solves(list):
    """The solves counted, each its arguments."""

    solve = staticmethod(steady_state.cracking_pressure)


def plan(model, loaded, changes, tank_input=None):
    settings = loaded.settings
    return plan_change(
        model, settings, changes, settings['initial_inlet_flow'], tank_input, SensorStage()
    )


def test_a_live_d_c_change_solves_the_cracking_point_once(model, loaded, solves):
    d_c = loaded.params['damping_orifice_diameter'] * 1.2
    solves.clear()
    planned = plan(model, loaded, {'damping_orifice_diameter': d_c})
    assert len(solves) == 1
    assert planned.problem is None
    assert planned.params['damping_orifice_diameter'] == d_c
    assert planned.parts.model == {'damping_orifice_diameter': d_c}
    assert planned.dependent == {
        'preset_pressure': steady_state.cracking_pressure(planned.params)
    }
    assert planned.changes['preset_pressure'] == planned.dependent['preset_pressure']


def test_a_new_preset_sets_the_preload_and_agrees_with_it(model, loaded):
    preset = steady_state.cracking_pressure(loaded.params) + 2e5
    planned = plan(model, loaded, {'preset_pressure': preset})
    assert planned.problem is None
    preload = planned.dependent['pilot_spring_preload']
    assert planned.params['pilot_spring_preload'] == preload
    assert steady_state.cracking_pressure(planned.params) == pytest.approx(preset, rel=1e-9)


def test_refusals_are_the_plan_s_problem_not_an_exception(model, loaded):
    refused = plan(model, loaded, {'burst_pressure': 1e6})
    assert 'exceeds burst_pressure' in refused.problem and refused.params is None
    disagreeing = plan(
        model,
        loaded,
        {'preset_pressure': 9e6, 'pilot_spring_preload': loaded.params['pilot_spring_preload']},
    )
    assert 'disagrees' in disagreeing.problem
    unreachable = plan(model, loaded, {'preset_pressure': 1e5})
    assert 'pilot_spring_preload' in unreachable.problem and unreachable.params is None


def test_a_preset_and_preload_that_agree_are_accepted_as_they_are(model, loaded):
    preload = loaded.params['pilot_spring_preload']
    preset = steady_state.cracking_pressure(loaded.params)
    planned = plan(model, loaded, {'preset_pressure': preset, 'pilot_spring_preload': preload})
    assert planned.problem is None and planned.dependent == {}
    assert planned.params['pilot_spring_preload'] == preload


def test_a_tank_pressure_solves_the_cracking_point_at_it_too(model, loaded, solves):
    ambient = loaded.settings['ambient_pressure']
    d_c = loaded.params['damping_orifice_diameter'] * 1.2
    solves.clear()
    planned = plan(model, loaded, {'damping_orifice_diameter': d_c}, ambient + 1e5)
    assert planned.problem is None and planned.tank_pressure == pytest.approx(1e5)
    assert len(solves) == 2  # the preset at ambient, the limit at the back pressure
