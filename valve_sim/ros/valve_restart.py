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
valve_node's restart: the state of a fresh start, in the running process (~/restart).

A suite of scenarios (ros.scenario_suite) and the kit's session fixture
(valve_sim.testing) run many tests on one valve_node; each must start where a new
process would. The service ~/restart (rcl_interfaces/srv/SetParametersAtomically)
does that in a few milliseconds: every parameter back to its start-up value (the
defaults, the launch's -p and --params-file), with the request's parameters over them
as if they had been given at start-up too (initial_inlet_flow, read-only otherwise,
included; preset_pressure given sets the preload, else it follows the others, as at
start-up); faults, sensors (their lag and noise from the seed again) and the fault
schedule as those values say; the tank_pressure topic's value and every input
received forgotten; a new model (un-halted, no roll-back pending, its invariant
monitor fresh) at the exact steady state of initial_inlet_flow and tank_pressure; and
a new time base: the node's clock goes back to zero through its guard, so the next
/clock (whatever its time) anchors the model time as a first /clock does, its tick
timer first due there. Everything is built and checked before anything changes: a
refused restart (its reason in the response) leaves the node as it was. Other
read-only parameters (use_sim_time, lockstep_inputs, ...) cannot change without a new
process: a request that changes one is refused.
"""

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter
from valve_sim.core.catalogue import split
from valve_sim.core.errors import InputFileError, ParameterError, SteadyStateError
from valve_sim.core.faults import HEALTHY
from valve_sim.core.parameters import PRESET_PRESSURE, SETTING_SPECS, SPECS, validate
from valve_sim.core.realtime_model import RealTimeModel
from valve_sim.core.sensors import checked_settings, default_settings
from valve_sim.core.steady_state import cracking_pressure, preload_for_cracking_pressure
from valve_sim.ros.fault_injection import FaultInjection, ScheduleLoader
from valve_sim.ros.ros_parameters import value_problem
from valve_sim.ros.valve_inputs import TankPressureInput
from valve_sim.ros.valve_parameters import VALVE_SPECS


SERVICE = '~/restart'
START_ONLY = ('initial_inlet_flow',)  # read-only, yet a restart starts from a new one
PRELOAD = 'pilot_spring_preload'


class StartValues:
    """A node's parameter values as set up, and whether its launch gave preset_pressure."""

    def __init__(self, node):
        names = node.list_parameters([], 0).names
        self.values = {name: node.get_parameter(name).value for name in names}
        self.read_only = {name for name in names
                          if node.describe_parameter(name).read_only}
        # rclpy's only record of the launch's values (see valve_parameters.overridden_names)
        self.preset_given = PRESET_PRESSURE.name in node._parameter_overrides

    def with_overrides(self, overrides):
        """
        Return the start-up values with overrides {name: value} as if given at start-up.

        Raises ParameterError naming a parameter the node lacks, a wrong value, or a
        read-only one that only a new process can change.
        """
        values = dict(self.values)
        for name, value in overrides.items():
            if name not in values:
                raise ParameterError(f'valve_node has no parameter {name!r}')
            if name in VALVE_SPECS:
                problem = value_problem(VALVE_SPECS[name], Parameter(name, value=value))
                if problem:
                    raise ParameterError(problem)
                value = float(value)
            if name in self.read_only and name not in START_ONLY and value != values[name]:
                raise ParameterError(f'parameter {name!r} is read-only: a restart keeps '
                                     f'{values[name]!r}; start a new valve_node for {value!r}')
            values[name] = value
        params = {name: values[name] for name in SPECS}
        if PRESET_PRESSURE.name in overrides or self.preset_given:
            values[PRELOAD] = preload_for_cracking_pressure(
                validate(params), values[PRESET_PRESSURE.name])
        else:
            values[PRESET_PRESSURE.name] = cracking_pressure(validate(params))
        return values


class Restart:
    """
    A node's start-up state, built from start values: the model, the injection, the settings.

    Raises ParameterError, SteadyStateError or InputFileError for values a start refuses.
    """

    def __init__(self, values):
        self.values = values
        self.params = validate({name: values[name] for name in SPECS})
        self.settings = {name: values[name] for name in SETTING_SPECS}
        parts = split({name: value for name, value in values.items()
                       if name.startswith(('fault.', 'sensor.')) or name == 'fault_schedule'})
        faults = HEALTHY.changed(parts.fault)
        sensors = checked_settings(default_settings(), parts.sensor)
        self.injection = FaultInjection(sensors, values.get('fault_schedule', ''))
        ambient = self.settings['ambient_pressure']
        problem = TankPressureInput(ambient, self.params['burst_pressure']).problem(
            self.settings['tank_pressure'] + ambient)
        if problem:
            raise ParameterError(f"parameter 'tank_pressure' (p_t): {problem}")
        self.model = RealTimeModel(self.params, self.settings['step_size'],
                                   self.settings['initial_inlet_flow'], faults,
                                   self.settings['tank_pressure'], ambient)


def restart(node, overrides):
    """
    Put a ReliefValveNode in its start-up state with overrides {name: value}; return the Restart.

    Raises ParameterError, SteadyStateError or InputFileError, the node unchanged.
    """
    values = node.start_values.with_overrides(overrides)
    fresh = Restart(values)
    node.take_inputs()  # what came before the restart is taken and forgotten below
    for _, subscription, taker in node.lockstep_inputs.inputs:
        while taker.take(subscription):
            pass
    if node.schedule_loader.loading:  # a schedule file still being read: never used now
        node.schedule_loader.close()
        node.schedule_loader = node.parameters.schedule_loader = ScheduleLoader()
    node.model = node.parameters.model = fresh.model  # before set_declared: its callbacks
    node.injection = node.parameters.injection = fresh.injection  # read the model in use
    node.parameters.set_declared({name: value for name, value in values.items()
                                  if name not in node.start_values.read_only})
    for name in START_ONLY:  # rclpy has no public way to set a read-only parameter
        node._parameters[name] = Parameter(name, value=values[name])
    node.parameters.undo = {}
    node.parameters._limit_inputs(fresh.params, fresh.settings)
    node.input.restart(fresh.settings['initial_inlet_flow'])
    node.tank_input.restart(None)
    node.applied_flow = node.inlet_flow
    node.use_settings(fresh.settings)
    node.status.restart()  # diagnostics count anew, as from a start (restarts: how many)
    node.diagnostics.restart()
    node.lockstep_inputs.late = 0
    node.clock_guard.restart()
    node.publish_fault_status()
    return fresh


def serve(node):
    """Create node's ~/restart service (rcl_interfaces/srv/SetParametersAtomically)."""
    from rcl_interfaces.srv import SetParametersAtomically

    def on_restart(request, response):
        overrides = {p.name: Parameter.from_parameter_msg(p).value for p in request.parameters}
        try:
            fresh = restart(node, overrides)
        except (ParameterError, SteadyStateError, InputFileError, ValueError) as error:
            response.result = SetParametersResult(
                successful=False, reason=f'restart refused, nothing changed: {error}')
            node.get_logger().warn(response.result.reason)
            return response
        response.result = SetParametersResult(successful=True, reason=(
            f'restarted at the steady state of {fresh.settings["initial_inlet_flow"]:g} m^3/s'
            f', tank {fresh.settings["tank_pressure"]:g} Pa (gauge); the next /clock starts '
            'the model time'))
        node.get_logger().info(response.result.reason + (f'; over start-up: {overrides}'
                                                         if overrides else ''))
        return response

    return node.create_service(SetParametersAtomically, SERVICE, on_restart)
