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
valve_sim: a virtual direct-pressure-sensing water-hydraulic relief valve for ROS 2 test benches.

The package is built in wings, each importing only the wings below it:

    core       the model: parameters, Eqs. (1)-(16), integrator, steady state (numpy, scipy)
    fmu        the model as an FMI 2.0 co-simulation FMU's slave (pythonfmu)
    analysis   step-response measures, signal handling, reference data, plots
    recording  MCAP bags as rosbag2 writes them, CDR tick messages, a bag's signals
    ros        the nodes (valve_node, analyser_node): thin rclpy adapters; replay, demo run
    commands   the `valve-sim` command line: parse, call the library, print
    testing    the test kit for users' suites: a valve_node in lockstep, a pytest fixture

test/lint/test_layering.py keeps it so.
"""

__version__ = '0.1.0'
