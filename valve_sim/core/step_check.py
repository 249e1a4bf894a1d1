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
Whether a valve can be integrated at a step size at all: judged once, before a run.

The integrator splits a step into RK4 sub-steps down to integrator.MIN_SUB_STEP; a
valve whose bodies or chambers need shorter ones would diverge, so it is refused in
one line before the run (ParameterError) instead: integrator.step_problem() judges the
bodies (state-free) and the chambers at the start state, and max_flow_problem() the
chambers at the steady state of max_inlet_flow, the largest flow the valve accepts
(the chambers' rates grow with the flow: a 1 mm^3 intermediate chamber passes 5 L/min
and cannot pass 100 L/min at any sub-step allowed). Used by every run's start:
simulation.run_flows, the real-time model (node, FMU) on a start and a retune.
"""

from functools import lru_cache

from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import ParameterError, SteadyStateError
from valve_sim.core.faults import HEALTHY
from valve_sim.core.integrator import max_splits, step_problem, STEP_RATE_LIMIT
from valve_sim.core.model import fastest_chamber_rate
from valve_sim.core.steady_state import steady_state


def max_flow_problem(params, faults, step, tank_pressure=0.0):
    """
    Return why step [s] cannot integrate the valve at its max_inlet_flow, or None.

    params: validated parameter dict; faults: FaultSet; tank_pressure [Pa, gauge]. A
    valve with no steady state there (an overpressure, an unstable one) is not judged
    here: such a run meets its limit or its monitor instead.
    """
    return _max_flow_problem(tuple(sorted(params.items())), faults, step, tank_pressure)


@lru_cache(maxsize=256)
def _max_flow_problem(items, faults, step, tank_pressure):
    params = dict(items)
    flow = params['max_inlet_flow']
    try:
        state = steady_state(params, flow, faults, tank_pressure, stable=False)
    except SteadyStateError:
        return None
    rate = fastest_chamber_rate(state, coefficients(params, faults), tank_pressure)
    needed, limit = int(step * rate / STEP_RATE_LIMIT) + 1, max_splits(step)
    if needed <= limit:
        return None
    return (
        f'this valve cannot be integrated up to max_inlet_flow = {flow:g} m^3/s at step size '
        f'{step:g} s: at that flow a chamber relaxes at {rate:.4g} 1/s, which needs {needed} '
        f'sub-steps of RK4 per step, more than the {limit} allowed (sub-steps of '
        f'{step / limit:.3g} s); lower max_inlet_flow or use larger chambers'
    )


def check_integrable(params, step, state=None, faults=HEALTHY, tank_pressure=0.0):
    """
    Raise ParameterError if step [s] cannot integrate the valve (params, faults).

    state: the start state (its chambers are judged too), or None; tank_pressure
    [Pa, gauge] there.
    """
    problem = step_problem(coefficients(params, faults), step, state, tank_pressure) or (
        max_flow_problem(params, faults, step, tank_pressure)
    )
    if problem:
        raise ParameterError(problem)
