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

"""The paper's Figure 5 values and the tolerances the reference model must meet (issue 2)."""

from valve_sim.analysis.paper import FIGURE5_MEASURES


TOLERANCES = {  # measure: (tolerance, 'rel' of the paper's value or 'abs')
    'T_1_ms': (0.10, 'rel'),
    'T_d_ms': (0.10, 'rel'),
    'P_1_percent': (0.15, 'rel'),
    'r_d': (0.03, 'abs'),
    'T_s_ms': (0.20, 'rel'),
    'P_o_percent': (0.30, 'rel'),
}


def outside_tolerance(measures):
    """Return {name: message} of the measures outside their tolerance (undefined ones too)."""
    problems = {}
    for name, (tolerance, kind) in TOLERANCES.items():
        paper, value = FIGURE5_MEASURES[name], measures[name]
        allowed = tolerance * paper if kind == 'rel' else tolerance
        if value is None or not abs(value - paper) <= allowed:
            problems[name] = f'{value} vs paper {paper} +- {allowed:.4g}'
    return problems
