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
The exact static characteristic: supply pressure and main-stage flow over inlet flow.

Built on the exact steady state (valve_sim.core.steady_state) for the characteristic
command and analysis: steady_curve samples it, flow_for_main_stage_flow inverts it for
the inlet flow at which the main stage passes a given flow (the cracking flow). Kept
apart from the steady state so that valve_node's start, which needs only one steady
state, does not import scipy.optimize (brentq) with it.
"""

import numpy as np
from scipy.optimize import brentq
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import SteadyStateError
from valve_sim.core.model import flows, P_S
from valve_sim.core.steady_state import steady_state


def steady_curve(params, inlet_flows):
    """
    Exact static characteristic: (p_s [Pa], main-stage flow q_m2 [m^3/s]) at each inlet flow.

    NaN where no steady state is found.
    """
    c = coefficients(params)
    pressure, main = np.full(len(inlet_flows), np.nan), np.full(len(inlet_flows), np.nan)
    for k, inlet_flow in enumerate(inlet_flows):
        try:
            state = steady_state(params, inlet_flow, stable=False)
        except SteadyStateError:
            continue
        pressure[k], main[k] = state[P_S], flows(state, c)[1]
    return pressure, main


def flow_for_main_stage_flow(params, main_flow, max_flow):
    """
    Inlet flow [m^3/s] at which the steady main-stage flow q_m2 equals main_flow [m^3/s].

    Searched between 0 and max_flow [m^3/s] (Brent's method on the exact steady
    state); raises SteadyStateError if the main stage does not pass main_flow there.
    """
    c = coefficients(params)

    def excess(inlet_flow):
        return flows(steady_state(params, inlet_flow, stable=False), c)[1] - main_flow

    if excess(max_flow) < 0.0:
        raise SteadyStateError(
            f'the main stage passes less than {main_flow:g} m^3/s up to {max_flow:g} m^3/s'
        )
    return brentq(excess, main_flow, max_flow, xtol=1e-15, rtol=1e-13)
