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
Physical limits of the valve, and the one check of inlet flows and states against them.

Two parameters bound what the model may be asked and what it may report
(docs/model.md, "Physical limits"):

- max_inlet_flow [m^3/s]: a larger inlet flow is not an input this valve can be
  given (valve_node rejects and counts it, the steady-state solver refuses it);
- burst_pressure [Pa, gauge]: no chamber of the real valve gets beyond it, and no
  tank pressure at or beyond it is an input (the tank port is part of the body).

A state is judged by state_check(): OK; OVERPRESSURE, a finite state with a chamber
beyond burst_pressure (physics: a fault or a flow the valve cannot relieve drove the
supply there, or a tank pressure stepped near the limit slammed the main valve open
and its swept volume compressed the pilot chamber beyond the tank); or DIVERGED, a
state that is not finite or beyond what any water-filled chamber can hold in any
case. Which chamber rose first says nothing about numerics: the integrator calls a
crossing an overpressure only if the step that made it was accurate (one step and two
half steps agree, integrator.crossing_is_accurate), else a divergence. The
steady-state solver, a reset, the integrator after every step and so every published
state go through it.
"""

import math

import numpy as np
from valve_sim.core.jit import jit
from valve_sim.core.model import P_C, P_S, STATE_NAMES


STATE_OK, STATE_OVERPRESSURE, STATE_DIVERGED = 0, 1, 2
# Beyond these [Pa, gauge] the integration broke down, whatever the parameters: water
# holds no 10 bar below vacuum, and no chamber reaches 1 GPa (burst_pressure's maximum).
PRESSURE_FLOOR = -1e6
NUMERICAL_CEILING = 1e9


@jit
def state_check(state, burst_pressure):
    """Return STATE_OK, STATE_OVERPRESSURE or STATE_DIVERGED for an 8-state (array or tuple)."""
    total = 0.0
    for i in range(len(state)):
        total += state[i]
    if total - total != 0.0:  # inf or nan anywhere makes the sum non-finite
        return STATE_DIVERGED
    beyond_burst = False
    for i in range(P_S, P_C + 1):
        if state[i] < PRESSURE_FLOOR or state[i] > NUMERICAL_CEILING:
            return STATE_DIVERGED
        beyond_burst = beyond_burst or state[i] > burst_pressure
    return STATE_OVERPRESSURE if beyond_burst else STATE_OK


def highest_chamber(state):
    """Return the index (P_S..P_C) of the chamber at the highest pressure of a state."""
    return max(range(P_S, P_C + 1), key=lambda i: state[i])


def inlet_flow_problem(flow, max_inlet_flow):
    """Return why an inlet flow [m^3/s] is not a valid input, or None if it is."""
    if isinstance(flow, bool) or not isinstance(flow, (int, float)):
        return f'inlet flow must be a number in m^3/s, got {flow!r}'
    if not math.isfinite(flow) or flow < 0.0:
        return f'inlet flow must be finite and >= 0 m^3/s, got {flow!r}'
    if flow > max_inlet_flow:
        return (
            f'inlet flow {flow:g} m^3/s exceeds max_inlet_flow (q_in,max) = '
            f'{max_inlet_flow:g} m^3/s'
        )
    return None


def tank_pressure_problem(pressure, burst_pressure, ambient_pressure=None):
    """
    Return why a tank pressure [Pa, gauge] is not a valid input, or None if it is.

    Valid: a finite number below burst_pressure [Pa, gauge] and not below vacuum:
    absolute (pressure + ambient_pressure [Pa]) at least 0 where the ambient pressure
    is known, else not below PRESSURE_FLOOR.
    """
    if isinstance(pressure, bool) or not isinstance(pressure, (int, float)):
        return f'tank pressure must be a number in Pa, got {pressure!r}'
    if not math.isfinite(pressure):
        return f'tank pressure must be finite, got {pressure!r}'
    if ambient_pressure is not None and pressure + ambient_pressure < 0.0:
        return (
            f'tank pressure {pressure + ambient_pressure:g} Pa absolute ({pressure:g} Pa gauge) '
            'is below vacuum'
        )
    if pressure < PRESSURE_FLOOR:
        return f'tank pressure {pressure:g} Pa (gauge) is below {PRESSURE_FLOOR:g} Pa'
    if pressure >= burst_pressure:
        return (
            f'tank pressure {pressure:g} Pa (gauge) is not below burst_pressure (p_burst) = '
            f'{burst_pressure:g} Pa'
        )
    return None


def schedule_problem(flows, max_inlet_flow):
    """Return why an inlet-flow schedule (array [m^3/s]) has an invalid flow, or None."""
    if len(flows) == 0:
        return None
    for flow in (float(np.min(flows)), float(np.max(flows))):
        problem = inlet_flow_problem(flow, max_inlet_flow)
        if problem:
            return problem
    if not np.all(np.isfinite(flows)):
        return 'inlet flow must be finite'
    return None


def describe_state(state):
    """Return 'name=value, ...' of an 8-state."""
    return ', '.join(f'{name}={value:.6g}' for name, value in zip(STATE_NAMES, state))


def state_problem(state, burst_pressure):
    """
    Return why a state is impossible, or None if it is within the limits.

    A finite state with a chamber beyond burst_pressure [Pa]
    is an overpressure of its highest chamber, however high (a steady state at an
    absurd flow); anything else state_check() refuses is not a physical state at all.
    """
    if state_check(state, float(burst_pressure)) == STATE_OK:
        return None
    chamber = highest_chamber(state)
    if math.isfinite(sum(state)) and state[chamber] > burst_pressure:
        return (
            f'overpressure: {STATE_NAMES[chamber]} = {state[chamber]:.6g} Pa (gauge) exceeds '
            f'burst_pressure (p_burst) = {burst_pressure:g} Pa'
        )
    return f'not a physical state: {describe_state(state)}'
