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
change, check_preset() verifies that a change keeps the two consistent, and
check_limits() that the running valve stays within its physical limits.
"""

import math

from valve_sim.core.catalogue import split
from valve_sim.core.errors import ParameterError
from valve_sim.core.limits import inlet_flow_problem, state_problem, tank_pressure_problem
from valve_sim.core.parameters import SPECS, validate
from valve_sim.core.steady_state import cracking_pressure, preload_for_cracking_pressure


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


def check_preset(params, changes):
    """
    Raise unless a change keeps preset_pressure the cracking pressure of params (merged).

    valve_node adds the dependent parameter to every change; where it is missing,
    deriving it failed, and repeating that raises the reason.
    """
    preset = changes.get('preset_pressure')
    if preset is None:
        if changes.keys() & SPECS.keys():
            cracking_pressure(params)
        return
    if 'pilot_spring_preload' not in changes:
        preload_for_cracking_pressure(params, preset)
    cracking = cracking_pressure(params)
    if not math.isclose(cracking, preset, rel_tol=PRESET_TOLERANCE):
        raise ParameterError(
            f'preset_pressure = {preset:g} Pa disagrees with the cracking pressure '
            f'{cracking:g} Pa given by '
            f'pilot_spring_preload = {params["pilot_spring_preload"]:g} m; set only one of the two'
        )


def check_limits(params, state, inlet_flow, tank_pressure=0.0, ambient_pressure=None):
    """
    Raise ParameterError unless params keep the running valve within its physical limits.

    The current inputs, inlet flow [m^3/s] and tank pressure [Pa, gauge, above vacuum
    at ambient_pressure if given], must stay valid (max_inlet_flow, burst_pressure), the
    current state below burst_pressure, and the valve must crack below burst_pressure
    at that back pressure (a relief valve that cannot open before its body bursts
    relieves nothing).
    """
    problem = inlet_flow_problem(inlet_flow, params['max_inlet_flow']) or tank_pressure_problem(
        tank_pressure, params['burst_pressure'], ambient_pressure
    )
    if problem:
        raise ParameterError(f'the current input would be refused: {problem}')
    problem = state_problem(state, params['burst_pressure'])
    if problem:
        raise ParameterError(f'the current state would be refused: {problem}')
    cracking = cracking_pressure(params, tank_pressure=tank_pressure)
    if cracking >= params['burst_pressure']:
        raise ParameterError(
            f'the valve would crack at {cracking:g} Pa, not below burst_pressure (p_burst) = '
            f'{params["burst_pressure"]:g} Pa'
            + (f' (tank pressure {tank_pressure:g} Pa)' if tank_pressure else '')
        )
