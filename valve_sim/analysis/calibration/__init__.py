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
Parameter identification: fit the model to measures or to a recording.

Lives here: fit (the search: calibrate, CalibrationProblem, FitSettings), parameters
(what can be fitted and its bounds, ties), targets (measures or a recording to fit),
requirements (constraints and checks of a fit), uncertainty (intervals, correlations),
verdict (does the fit explain the target), report (the report and fit.png).
May import: valve_sim.core, valve_sim.analysis.paper, the steps and studies rooms,
plotting and recorded_steps.
"""
