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
Bench scenarios as files: a YAML bench test, its expectations and its judgement.

Lives here: bench_scenario (BenchScenario: the file read and checked), expectations
(what a scenario expects of the run), tick_series (the run's ticks as signals),
report (the judgement as text, JSON, JUnit and a figure). Not the core's FlowStep
(one inlet-flow step test).
May import: valve_sim.core, valve_sim.analysis.paper, the steps room and plotting.
"""
