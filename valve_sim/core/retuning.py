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
What a live parameter change of valve_node implies, without ROS.

preset_pressure is the valve's cracking pressure: the steady supply pressure
(gauge) at which the main valve lifts off its seat (steady_state.cracking_pressure).
Setting it sets pilot_spring_preload, the way a technician turns the adjusting
screw; changing any model parameter moves the cracking pressure, which
preset_pressure then reports. dependent_change() derives the partner of a
change, planned_parameters() the parameters after it with the two consistent
(solving the cracking point once), and check_limits() checks that the running
valve stays within its physical limits. plan_change() does all of that for a
running model at once (valve_node, the FMU), solving the cracking point once: a
ChangePlan that the caller checks, then applies.
"""

from dataclasses import dataclass
import math

from valve_sim.core.catalogue import Change, split
from valve_sim.core.errors import IntegrationError, ParameterError, SteadyStateError
from valve_sim.core.limits import inlet_flow_problem, state_problem, tank_pressure_problem
from valve_sim.core.parameters import check_value, SPECS, validate
from valve_sim.core.realtime_model import TRIAL_STEPS
from valve_sim.core.steady_state import (
    cracking_pressure,
    preload_for_cracking_pressure,
    preset_preload,
)


PRESET_TOLERANCE = 1e-6  # relative agreement of preset_pressure and the cracking pressure


def merged_parameters(params, changes):
    """
    Return a validated copy of params with the model parameters in changes applied.

    params: the model parameters. changes: {name: value} of any parameters; only
    its model part (catalogue.split) is used. Raises ParameterError.
    """
    return validate({**params, **split(changes).model})


def dependent_change(params, changes):
    """
    Return the parameter a change implies, as {name: value}.

    preset_pressure [Pa] sets pilot_spring_preload [m]; a change of any model
    parameter gives the new cracking pressure as preset_pressure. Raises
    ParameterError or SteadyStateError if it cannot be derived.
    """
    if 'preset_pressure' in changes and 'pilot_spring_preload' not in changes:
        merged = merged_parameters(params, changes)
        return {
            'pilot_spring_preload': preload_for_cracking_pressure(
                merged, changes['preset_pressure']
            )
        }
    if 'preset_pressure' not in changes and changes.keys() & SPECS.keys():
        return {'preset_pressure': cracking_pressure(merged_parameters(params, changes))}
    return {}


def _check_agreement(params, preset, cracking):
    """Raise unless preset_pressure [Pa] is the cracking pressure [Pa] of params."""
    if not math.isclose(cracking, preset, rel_tol=PRESET_TOLERANCE):
        raise ParameterError(
            f'preset_pressure = {preset:g} Pa disagrees with the cracking pressure '
            f'{cracking:g} Pa given by '
            f'pilot_spring_preload = {params["pilot_spring_preload"]:g} m; set only one of the two'
        )


def check_limits(
    params, state, inlet_flow, tank_pressure=0.0, ambient_pressure=None, cracking=None
):
    """
    Raise ParameterError unless params keep the running valve within its physical limits.

    The current inputs, inlet flow [m^3/s] and tank pressure [Pa, gauge, above vacuum
    at ambient_pressure if given], must stay valid (max_inlet_flow, burst_pressure), the
    current state below burst_pressure, and the valve must crack below burst_pressure
    at that back pressure (a relief valve that cannot open before its body bursts
    relieves nothing). cracking: that cracking pressure [Pa] if known (else solved).
    """
    problem = inlet_flow_problem(inlet_flow, params['max_inlet_flow']) or tank_pressure_problem(
        tank_pressure, params['burst_pressure'], ambient_pressure
    )
    if problem:
        raise ParameterError(f'the current input would be refused: {problem}')
    problem = state_problem(state, params['burst_pressure'])
    if problem:
        raise ParameterError(f'the current state would be refused: {problem}')
    if cracking is None:
        cracking = cracking_pressure(params, tank_pressure=tank_pressure)
    if cracking >= params['burst_pressure']:
        raise ParameterError(
            f'the valve would crack at {cracking:g} Pa, not below burst_pressure (p_burst) = '
            f'{params["burst_pressure"]:g} Pa'
            + (f' (tank pressure {tank_pressure:g} Pa)' if tank_pressure else '')
        )


@dataclass(frozen=True)
class ChangePlan:
    """
    One live parameter change of valve_node, planned once: what it sets and implies.

    changes: {name: value} as asked, with the dependent parameter added; parts: its
    catalogue.split; params, settings: the model parameters and run-time settings after
    it; dependent: {'preset_pressure': Pa} or {'pilot_spring_preload': m} the change
    implies, or {}; tank_pressure: the tank pressure [Pa, gauge] under the new settings;
    problem: why the change is refused, or None (then params and settings are set).
    """

    changes: dict
    parts: Change
    params: dict = None
    settings: dict = None
    dependent: dict = None
    tank_pressure: float = None
    problem: str = None


def plan_change(model, settings, changes, inlet_flow, tank_input, sensors):
    """
    Plan a live change {name: value} of the RealTimeModel model's node, solving once.

    settings: the run-time settings in use; inlet_flow [m^3/s]: the input the next tick
    applies; tank_input: the tank pressure topic's last value [Pa, absolute], or None;
    sensors: the SensorStage. Derives the dependent parameter (one cracking-point solve,
    a few for a new preset), then checks in order: settings, model parameters, preset,
    faults, sensor settings, the valve's limits at the current state and inputs (the
    same cracking point at ambient tank pressure), and a trial integration from the
    current state. Returns a ChangePlan; a refusal is its problem, never an exception.
    """
    plan = {'dependent': {}}
    try:
        new_settings = {
            **settings,
            **{name: check_value(name, value) for name, value in split(changes).setting.items()},
        }
        params, cracking, plan['dependent'] = planned_parameters(model.params, changes)
        model.faults.changed(split(changes).fault)
        sensors.checked(split(changes).sensor)
        ambient = new_settings['ambient_pressure']
        tank = new_settings['tank_pressure'] if tank_input is None else tank_input - ambient
        check_limits(
            params, model.state, inlet_flow, tank, ambient, cracking if tank == 0 else None
        )
        model.trial(
            params, new_settings['step_size'], inlet_flow, split(changes).fault or None, tank
        )
    except IntegrationError as error:
        plan['problem'] = (
            f'the integration would diverge (trial of {TRIAL_STEPS} steps '
            f'from the current state): {error}'
        )
    except (ParameterError, SteadyStateError) as error:
        plan['problem'] = str(error)
    else:
        plan.update(params=params, settings=new_settings, tank_pressure=tank)
    changes = {**changes, **plan['dependent']}
    return ChangePlan(changes, split(changes), **plan)


def planned_parameters(params, changes):
    """
    Return (params, cracking pressure [Pa] or None, dependent change) of a change.

    params: the model parameters in use; changes: {name: value}, of which the model
    parameters and preset_pressure count. The params returned are merged with the
    change and validated, the preset and the preload agreeing: a new preset sets the
    preload (a few cracking-point solves), a new model parameter the preset (one).
    Raises ParameterError or SteadyStateError.
    """
    params = merged_parameters(params, changes)
    preset = changes.get('preset_pressure')
    if preset is not None and 'pilot_spring_preload' not in changes:
        preload, cracking = preset_preload(params, preset)
        params = {**params, 'pilot_spring_preload': preload}
        dependent = {'pilot_spring_preload': preload}
    elif preset is not None or changes.keys() & SPECS.keys():
        cracking = cracking_pressure(params)
        dependent = {} if preset is not None else {'preset_pressure': cracking}
    else:
        return params, None, {}
    _check_agreement(params, changes.get('preset_pressure', cracking), cracking)
    return params, cracking, dependent
