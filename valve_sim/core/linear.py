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
Linear modes of the valve about a steady state: how fast and how damped it rings.

The Jacobian of the model's right-hand side is taken by central differences
(steps scaled per state) at the exact steady state; its complex eigenvalues
lambda give the modes: frequency |Im lambda| / 2 pi and damping ratio
-Re lambda / |lambda|. Used to check stability margins (docs/model.md).
"""

import numpy as np
from valve_sim.core.model import coefficients, state_derivative
from valve_sim.core.steady_state import steady_state


STATE_SCALE = np.array([1e6] * 4 + [1e-4, 1e-2, 1e-5, 1e-2])  # typical size of each state


def jacobian(params, state, inlet_flow, relative_step=1e-6):
    """d(state_dot)/d(state) [8 x 8] at state for inlet flow [m^3/s]."""
    c = coefficients(params)
    matrix = np.empty((8, 8))
    for j in range(8):
        delta = np.zeros(8)
        delta[j] = STATE_SCALE[j] * relative_step
        matrix[:, j] = (
            state_derivative(state + delta, inlet_flow, c)
            - state_derivative(state - delta, inlet_flow, c)
        ) / (2.0 * delta[j])
    return matrix


def oscillatory_modes(params, inlet_flow):
    """
    Return [(frequency [Hz], damping ratio [-])] of the oscillatory modes at the steady state.

    The slowest mode comes first.
    """
    state = steady_state(params, inlet_flow)
    eigenvalues = np.linalg.eigvals(jacobian(params, state, inlet_flow))
    modes = [(abs(e.imag) / (2 * np.pi), -e.real / abs(e)) for e in eigenvalues if e.imag > 1e-6]
    return sorted(modes)


def slowest_decay_rate(params, inlet_flows):
    """
    Return the slowest decay rate -Re(lambda) [1/s] of the linear modes at the steady states.

    Every eigenvalue of the Jacobian at the steady state of each inlet flow [m^3/s]
    counts, oscillatory or not; negative: a mode that grows (the valve is unstable).
    Raises SteadyStateError where a steady state cannot be found.
    """
    return min(
        float(np.min(-np.linalg.eigvals(jacobian(params, steady_state(params, flow), flow)).real))
        for flow in inlet_flows
    )
