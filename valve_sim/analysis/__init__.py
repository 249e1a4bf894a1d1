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
Response analysis on arrays: the six step-response measures, studies, calibration, figures.

Lives here, in rooms (sub-packages, each __init__ says what it holds and may import),
one-way from the bottom up:
  paper            the paper's reference data (Table 1-3, Figure 5), no import of the wing
  steps/           the six measures of a step, finding steps, signals, the envelope check,
                   a simulated step's report (simulated_step)
  characteristic   the static characteristic (and the model's ramp test)
  plotting         matplotlib figures (Figure 5, the characteristic)
  recorded_steps   the steps of a recording: measures, Figure 5, their text
  studies/         the parameter study, tolerance and sensitivity studies on a backend
  calibration/     parameter identification: the fit, its uncertainty, verdict and report
  design/          robust design optimisation: yield of a design, the Pareto search
  scenarios/       bench scenarios as YAML files (BenchScenario), expectations, reports
May import: valve_sim.core. No ROS and no bag files: recording reads bags and hands
arrays to this wing. test/lint/test_layering.py holds each room to its rule.
"""
