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
Linear stability of an equilibrium of Eqs. (1)-(16): whether the valve comes back to it.

An equilibrium solves every balance (steady_state) but the valve rests there only if
every linear mode about it decays. The Jacobian of the right-hand side is taken by
central differences (steps scaled per state); a valve resting on a seat or end stop
and pushed into it is held there by the stop, so its position and velocity take no
part (their rows and columns are left out: the stop makes the model non-smooth
there). valve_sim.core.linear names the modes of a stable state.
"""

import numpy as np
from valve_sim.core.model import net_forces, state_derivative, X, X_DOT, Y, Y_DOT


STATE_SCALE = np.array([1e6] * 4 + [1e-4, 1e-2, 1e-5, 1e-2])  # typical size of each state
# A mode grows when Re(lambda) exceeds this share of |lambda| (and GROWTH_FLOOR [1/s]):
# the finite differences' error is far below both.
GROWTH_SHARE = 1e-6
GROWTH_FLOOR = 1e-3


def jacobian_of(c, state, inlet_flow, tank_pressure=0.0, relative_step=1e-6):
    """d(state_dot)/d(state) [8 x 8] at state for Coefficients c, inlet flow and tank pressure."""
    matrix = np.empty((8, 8))
    for j in range(8):
        delta = np.zeros(8)
        delta[j] = STATE_SCALE[j] * relative_step
        matrix[:, j] = (
            state_derivative(state + delta, inlet_flow, c, tank_pressure)
            - state_derivative(state - delta, inlet_flow, c, tank_pressure)
        ) / (2.0 * delta[j])
    return matrix


def free_states(state, c, tank_pressure=0.0):
    """Return the indices of the states that move about state (a valve held by a stop: not)."""
    force_x, force_y = net_forces(state, c, tank_pressure)
    held = []
    for position, velocity, force, stroke in (
        (X, X_DOT, force_x, c.main_valve_stroke), (Y, Y_DOT, force_y, c.poppet_stroke)
    ):
        if state[position] <= 0.0 and force <= 0.0 or state[position] >= stroke and force >= 0.0:
            held += [position, velocity]
    if c.main_valve_free == 0.0:
        held += [X, X_DOT]
    return [i for i in range(8) if i not in held]


def growing_mode(c, state, inlet_flow, tank_pressure=0.0):
    """
    Return the fastest-growing eigenvalue about an equilibrium, or None if every mode decays.

    c: Coefficients (faults included); state: the equilibrium [8-array].
    """
    free = free_states(state, c, tank_pressure)
    matrix = jacobian_of(c, state, inlet_flow, tank_pressure)[np.ix_(free, free)]
    eigenvalues = np.linalg.eigvals(matrix)
    worst = eigenvalues[np.argmax(eigenvalues.real)]
    if worst.real > max(GROWTH_SHARE * abs(worst), GROWTH_FLOOR):
        return complex(worst)
    return None
