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
The six step-response measures of one inlet-flow step, and finding the steps.

Lives here: measures (step_measures, the measures' constants), measure_windows (the
windows and cuts a measure is taken over), input_events (which setting and parameter
changes end a window), sample_window (indices of sampled times),
step_detection (where a step is), step_analysis (streaming: joined rows in, one
record per step out), signals (the roles of recorded signals and their joining),
envelope (a waveform against the limits of an envelope).
May import: valve_sim.core and valve_sim.analysis.paper. Nothing else of the wing:
every other room builds on these.
"""
