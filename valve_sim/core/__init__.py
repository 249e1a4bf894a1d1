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
The valve model: parameters, equations (1)-(16), integration, steady state.

Lives here: the parameter catalogue (every parameter's spec, catalogue.py), parameter
files, the model equations and their coefficients, the RK4 integrator (one valve, or
many in lanes), the exact steady state, bearing design, linear modes, offline simulation
(single runs, and batch runs for studies), real-time stepping and live retuning; valve
faults, the pressure transducers' model (sensors) and fault schedule files; every error
valve_sim raises, under one root (errors); the kernels' build-time compile (precompile).
May import: numpy, scipy, yaml, numba, ament_index_python (to find the installed
config files); nothing else of valve_sim. No ROS middleware, no plotting, no bag formats.
"""
