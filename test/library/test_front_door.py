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

"""The library's front door: `import valve_sim as vs`, its Parameters, its checked simulate()."""

import math
import subprocess
import sys

import pytest
import valve_sim as vs
from valve_sim.commands import cli
from valve_sim.core.errors import ParameterError, UnavailableError
from valve_sim.core.flow_step import FlowStep
from valve_sim.core.realtime_model import RealTimeModel
from valve_sim.core.simulation import simulate, simulate_recorded_flow
from valve_sim.ros import isolation

SHORT = FlowStep(step_time=0.05, end_time=0.1)


def test_import_valve_sim_is_light_and_gives_every_verb():
    """The verbs are there, each imported from its wing only when first used."""
    code = (
        'import sys, valve_sim as vs\n'
        'heavy = [m for m in ("numba", "scipy", "rclpy", "matplotlib",'
        ' "valve_sim.core.simulation") if m in sys.modules]\n'
        'assert not heavy, heavy\n'
    )
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    missing = [name for name in vs.__all__ if not hasattr(vs, name)]
    assert missing == []
    with pytest.raises(AttributeError, match='no attribute'):
        vs.no_such_verb
    assert vs.__all__ == ['__version__', *vs._EXPORTS]  # the literal list type checkers read


def test_parameters_are_validated_when_built_immutable_and_replaced_by_name_or_symbol():
    valve = vs.Parameters()
    assert valve == vs.Parameters.load() and isinstance(valve['damping_orifice_diameter'], float)
    with pytest.raises(ParameterError, match="'bulk_modulus'.*outside its limits"):
        valve.replace(bulk_modulus=-1.0)
    with pytest.raises(ParameterError, match='missing parameter'):
        vs.Parameters({'bulk_modulus': 2e9})
    with pytest.raises(ParameterError, match="unknown parameter 'bulk_modulous'"):
        valve.replace(bulk_modulous=2e9)
    with pytest.raises(TypeError):
        valve['bulk_modulus'] = 1.0
    d_c = valve['damping_orifice_diameter']
    wider = valve.replace(d_c=d_c * 1.1)
    assert wider['damping_orifice_diameter'] == pytest.approx(d_c * 1.1)
    assert valve.scaled(d_c=10.0) == wider and wider != valve
    assert valve['damping_orifice_diameter'] == d_c  # unchanged: replace() made a copy
    assert 'damping_orifice_diameter' in repr(wider) and len({valve, vs.Parameters()}) == 1


def test_simulate_refuses_an_invalid_valve_with_a_parameter_error(reference):
    """Before: a negative bulk modulus ran (p_s flat); an empty dict raised KeyError."""
    with pytest.raises(ParameterError, match="'bulk_modulus'"):
        simulate(dict(reference, bulk_modulus=-1.0), FlowStep(end_time=0.3))
    with pytest.raises(ParameterError, match='missing parameter.*max_inlet_flow'):
        simulate({}, SHORT)
    with pytest.raises(ParameterError, match="'bulk_modulus'"):
        simulate_recorded_flow(dict(reference, bulk_modulus=-1.0), [0.0, 0.01], [1e-4, 1e-4])
    with pytest.raises(ParameterError, match="'bulk_modulus'"):
        RealTimeModel(dict(reference, bulk_modulus=-1.0), 1e-5, 1e-4)
    model = RealTimeModel(reference, 1e-5, 1e-4)
    with pytest.raises(ParameterError, match='missing parameter'):
        model.retune({}, 1e-5)


def test_a_run_is_a_result_with_status_and_message_and_plain_float_measures():
    valve = vs.Parameters()
    scenario = vs.FlowStep(step_time=0.05, end_time=0.3)
    run = vs.simulate(valve, scenario, record_interval=1e-3)
    assert (run.status, run.message) == (0, 'the run reached its end')
    measures = vs.step_measures(run.time, run['supply_pressure'],
                                run['main_valve_displacement'], scenario.step_time)
    values = [v for v in measures.values.values() if v is not None]
    assert values and all(type(v) is float for v in values), measures.values
    point = vs.operating_point(valve, scenario.initial_flow)
    assert point.status == 0 and type(point.supply_pressure) is float
    # integrated for 50 ms before the step, the valve stays at its operating point
    before = run.time < scenario.step_time
    assert run['supply_pressure'][before][-1] == pytest.approx(point.supply_pressure, rel=1e-6)
    assert all(math.isfinite(mode.decay_rate) for mode in point.modes)


def test_an_overpressure_halt_is_a_status_not_a_normal_result():
    """A burst pressure between the steady 5 L/min and 20 L/min pressures: the step halts."""
    valve = vs.Parameters(burst_pressure=7.2e6)
    run = vs.simulate(valve, SHORT, halt_on_overpressure=True)
    assert run.status == 1 and run.message.startswith('halted at 0.05'), run.message


def test_every_ros_domain_held_is_one_line_from_the_cli(monkeypatch, tmp_path, capsys):
    """Before: a bare RuntimeError, a traceback from `valve-sim demo` and `scenario run`."""
    def held(handle, flags):
        raise BlockingIOError('held')

    monkeypatch.setattr(isolation, 'LOCK_FOLDER', tmp_path / 'locks')
    monkeypatch.setattr(isolation, 'DOMAIN_IDS', range(1, 4))
    monkeypatch.setattr(isolation.fcntl, 'flock', held)
    with pytest.raises(UnavailableError, match='every ROS domain') as refused:
        isolation.claim_domain(keep_existing=False)
    assert isinstance(refused.value, RuntimeError)
    monkeypatch.delenv('ROS_DOMAIN_ID')  # the user's shell sets none: demo claims one
    assert cli.main(['demo', '--out', str(tmp_path / 'demo')]) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith('valve-sim demo: error: every ROS domain 1-101 is held')
