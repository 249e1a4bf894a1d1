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
Robust design optimisation: Pareto designs whose tolerance batch meets the limits.

Lives here: optimisation (the search over designs, pymoo), robust_yield (one
candidate's yield over its tolerance samples), sequential_yield (stopping a
candidate's sampling early, a sequential test), report and plots (the front).
May import: valve_sim.core, valve_sim.analysis.paper, the steps and studies rooms and
plotting.
"""
