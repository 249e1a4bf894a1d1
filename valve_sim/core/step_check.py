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

The integrator splits a step into RK4 sub-steps down to integrator.MIN_SUB_STEP, and takes
a step that a stiff chamber would split further with the stiff-stable ROS2; only a body
ringing faster than those sub-steps follow cannot be integrated (ROS2 would damp its ring
away). Such a valve is refused in one line before the run (ParameterError,
integrator.step_problem). Used by every run's start: simulation.run_flows, the real-time
model (node, FMU) on a start and a retune.
"""

from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import ParameterError
from valve_sim.core.faults import HEALTHY
from valve_sim.core.integrator import step_problem


def check_integrable(params, step, faults=HEALTHY):
    """Raise ParameterError if step [s] cannot integrate the valve (params, faults)."""
    problem = step_problem(coefficients(params, faults), step)
    if problem:
        raise ParameterError(problem)
