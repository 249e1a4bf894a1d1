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

"""valve_node's live parameter changes (ValveParameters), given what they need: no node."""

import math

import pytest
from rclpy.parameter import Parameter
from valve_sim.core import retuning
from valve_sim.core.parameters import FAULT_SCHEDULE, load_parameters
from valve_sim.core.realtime_model import RealTimeModel
from valve_sim.core.steady_state import cracking_pressure
from valve_sim.ros.fault_injection import FaultInjection
from valve_sim.ros.node_status import NodeStatus
from valve_sim.ros.valve_inputs import InletFlowInput, TankPressureInput
from valve_sim.ros.valve_parameters import NodeHooks, ValveParameters


class Declared(dict):
    """The node's declared parameters as ValveParameters uses them: a dict that sets."""

    def set_values(self, parameters):
        self.update({p.name: p.value for p in parameters})


class Logger:
    """rclpy's logger as ValveParameters uses it: every line kept with its severity."""

    def __init__(self):
        self.lines = []

    def __getattr__(self, severity):
        return lambda message: self.lines.append((severity, message))


class Valve:
    """A ValveParameters with the parts it acts on, and what it asked of the node."""

    def __init__(self):
        loaded = load_parameters()
        self.settings = dict(loaded.settings)
        self.model = RealTimeModel(loaded.params, self.settings['step_size'],
                                   self.settings['initial_inlet_flow'])
        self.injection = FaultInjection({})
        self.inlet = InletFlowInput(self.settings['initial_inlet_flow'],
                                    loaded.params['max_inlet_flow'])
        self.tank = TankPressureInput(self.settings['ambient_pressure'],
                                      loaded.params['burst_pressure'])
        self.status = NodeStatus(0)
        self.declared = Declared(
            {**loaded.params, **self.settings, 'preset_pressure': cracking_pressure(loaded.params),
             **self.model.faults.as_parameters(), **self.injection.sensors.settings,
             FAULT_SCHEDULE: ''}
        )
        self.asked = []  # what the node was asked: resume and publish_fault_status
        self.logger = Logger()
        self.parameters = ValveParameters(
            self.declared, self.model, self.injection, (self.inlet, self.tank),
            schedule_loader=None, status=self.status, hooks=NodeHooks(
                lambda: self.settings, self.use_settings,
                lambda cause: self.asked.append(f'resume after {cause}'),
                lambda: self.asked.append('publish_fault_status')),
            logger=self.logger,
        )

    def use_settings(self, settings):
        self.settings = settings

    def change(self, **values):
        """Set values as both parameter services do: the node's checks, then rclpy's callbacks."""
        return self.parameters.set_atomically(
            [Parameter(name, value=value) for name, value in values.items()], self._rclpy_sets
        )

    def _rclpy_sets(self, parameter_list):
        """Node.set_parameters_atomically: pre-set, on-set; if successful, set and post-set."""
        completed = self.parameters.complete(parameter_list)
        result = self.parameters.check(completed)
        if result.successful:
            self.declared.update({p.name: p.value for p in completed})
            self.parameters.apply(completed)
        return result


@pytest.fixture
def valve():
    return Valve()


def test_a_change_is_planned_once_applied_and_the_inputs_limits_follow(valve, monkeypatch):
    solves = []
    monkeypatch.setattr(retuning, 'cracking_pressure',
                        lambda *args: solves.append(args) or cracking_pressure(*args))
    params = dict(valve.model.params)
    d_c = params['damping_orifice_diameter'] * 1.2
    result = valve.change(
        damping_orifice_diameter=d_c, max_inlet_flow=2 * params['max_inlet_flow'],
        burst_pressure=1.1 * params['burst_pressure'], ambient_pressure=0.9e5,
    )
    assert result.successful, result.reason
    assert valve.model.params['damping_orifice_diameter'] == d_c
    assert len(solves) == 1, 'the cracking point is solved once, by the plan'
    assert valve.declared['preset_pressure'] == cracking_pressure(valve.model.params)
    assert valve.inlet.max_inlet_flow == 2 * params['max_inlet_flow']
    assert valve.tank.burst_pressure == 1.1 * params['burst_pressure']
    assert valve.tank.ambient_pressure == valve.settings['ambient_pressure'] == 0.9e5
    assert valve.asked == ['resume after a parameter change']
    assert valve.logger.lines[-1][0] == 'info' and 'parameters set' in valve.logger.lines[-1][1]
    assert valve.inlet.offer(1.5 * params['max_inlet_flow']), 'the new limit is in use'


def test_a_roll_back_undoes_the_whole_change_and_the_inputs_limits_follow_back(valve):
    before = dict(valve.declared)
    params = dict(valve.model.params)
    assert valve.change(
        damping_orifice_diameter=params['damping_orifice_diameter'] * 1.2,
        max_inlet_flow=2 * params['max_inlet_flow'], ambient_pressure=0.9e5, input_timeout=7.0,
    ).successful
    assert valve.model.roll_back(failure_ns=0)  # what a failure in the trial window does
    valve.parameters.restore()
    assert valve.model.params == params
    assert valve.declared == before, 'declared values agree with what is in use again'
    assert valve.settings['input_timeout'] == before['input_timeout']
    assert valve.inlet.max_inlet_flow == params['max_inlet_flow']
    assert valve.tank.ambient_pressure == valve.settings['ambient_pressure'] == 101325.0
    assert valve.asked[-1] == 'publish_fault_status'


def test_refusals_are_counted_and_logged_with_their_reason(valve):
    flow = valve.model.params['max_inlet_flow']
    bad_value = valve.change(damping_orifice_diameter=math.nan)
    undeclared = valve.change(damping_orifice_diametre=1e-3)
    unplannable = valve.change(burst_pressure=1e6)  # below the cracking pressure
    assert not (bad_value.successful or undeclared.successful or unplannable.successful)
    assert 'damping_orifice_diameter' in undeclared.reason  # the name meant
    assert 'exceeds burst_pressure' in unplannable.reason
    assert valve.status.counters.rejected_parameter_changes == 3
    warnings = [message for severity, message in valve.logger.lines if severity == 'warn']
    assert warnings == [f'parameter change refused: {r.reason}'
                        for r in (bad_value, undeclared, unplannable)]
    assert valve.model.params['max_inlet_flow'] == valve.inlet.max_inlet_flow == flow
    assert valve.asked == []


def test_a_scheduled_sensor_change_applies_directly_and_is_declared(valve):
    valve.model.start(2_000_000_000)
    name = next(n for n in valve.injection.sensors.settings if n.endswith('.dropout'))
    valve.parameters.apply_scheduled({name: True})
    assert valve.declared[name] is True and valve.injection.sensors.settings[name] is True
    assert valve.asked == ['publish_fault_status', 'resume after a scheduled fault']
    message = f"fault schedule at t = 2.000000 s: {{'{name}': True}}"
    assert valve.logger.lines == [('info', message)]
