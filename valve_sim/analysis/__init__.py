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
Response analysis on arrays: the six step-response measures, signals, plots.

Lives here: the measures and step detection, streaming step analysis, the steps of a
recording (recorded_steps: measures, Figure 5, their text), signal mapping and
joining, the paper's reference data and study cases (and the study run on a backend
sized for this machine: study_backend), tolerances, sensitivity and robust
optimisation, parameter identification (calibration: the fit, its uncertainty and its
report), the static characteristic (and the model's ramp test), the envelope check,
matplotlib figures.
May import: valve_sim.core. No ROS and no bag files: recording reads bags and hands
arrays to this wing.
"""
