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
Reference data from the paper (its Figure 5, Table 2 and Table 3), for comparison only.

Nothing in the model reads these; they are printed beside our results, and only
beside a run of the paper's own scenario (is_reference_step).
"""

import math

from valve_sim.core.flow_step import FlowStep, LITRE_PER_MINUTE


# Figure 5 / Table 3, Table 1 conditions, under the names of docs/measures.md.
FIGURE5_MEASURES = {
    'P_o_percent': 0.144,
    'P_1_percent': 3.18,
    'T_1_ms': 6.7,
    'r_d': 0.851,
    'T_d_ms': 25.1,
    'T_s_ms': 540.0,
}

# The paper's test: 5 L/min, +15 L/min step at 0.25 s, end at 1.25 s.
REFERENCE_FLOW_STEP = FlowStep(
    initial_flow=5.0 * LITRE_PER_MINUTE,
    final_flow=20.0 * LITRE_PER_MINUTE,
    step_time=0.25,
    end_time=1.25,
)

# The parameter study: each varied one at a time by these percentages.
STUDY_PARAMETERS = ('m_m', 'm_p', 'V_p', 'V_c', 'd_c', 'k_p')
STUDY_VARIATIONS = (-20, -10, 0, 10, 20)

# Table 2: the six parameters varied together [%].
TABLE2_CHANGES = {'m_m': -20, 'm_p': -20, 'V_p': 20, 'V_c': -20, 'd_c': 10, 'k_p': -20}


def is_reference_step(initial_flow, final_flow):
    """
    Whether an inlet-flow step [m^3/s] is the paper's 5 -> 20 L/min.

    Figure 5's values only describe that step; beside any other they compare nothing.
    """
    return all(
        math.isclose(flow, reference, rel_tol=1e-3)
        for flow, reference in (
            (initial_flow, REFERENCE_FLOW_STEP.initial_flow),
            (final_flow, REFERENCE_FLOW_STEP.final_flow),
        )
    )
