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
The valve as an FMI 2.0 co-simulation FMU (Functional Mock-up Unit), built with pythonfmu.

Lives here: relief_valve_slave, the FMU's slave class ReliefValve: a thin adapter that
maps FMI variables onto valve_sim.core's RealTimeModel, the model valve_node runs.
builder packs it with pythonfmu (build(), for `valve-sim fmu`); docs/fmu.md says how.
May import: valve_sim.core, pythonfmu. No ROS, no bags, no plots: the FMU runs inside
another tool's process.
"""
