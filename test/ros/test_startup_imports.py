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
valve_node imports only what its start needs (issue 29: a node that starts at once).

Its start needs rclpy and the messages, numba (the cached kernels) and numpy;
plotting, bag writers, studies, the FMU, the analysis and the commands would each
add tenths of a second to every start, and so would scipy.optimize (the steady state
uses valve_sim.core.newton, scipy's hybr only if Newton fails) and scipy.linalg (only
the linear modes need it). Checked in a fresh interpreter: the modules loaded by importing
valve_node and parsing its command line.
"""

import subprocess
import sys


NOT_AT_START = (
    'matplotlib',
    'mcap',
    'mcap_ros2',
    'rosbags',
    'dask',
    'distributed',
    'SALib',
    'pymoo',
    'fmpy',
    'pythonfmu',
    'foxglove',
    'websockets',
    'scipy.integrate',
    'scipy.interpolate',
    'scipy.linalg',
    'scipy.optimize',
    'scipy.signal',
    'scipy.stats',
    'valve_sim.analysis',
    'valve_sim.commands',
    'valve_sim.fmu',
    'valve_sim.recording.bag',
    'valve_sim.testing',
)
SCRIPT = """
import sys
from valve_sim.ros import valve_node_main
valve_node_main.parse_arguments(['valve_node'])
print('\\n'.join(sorted(sys.modules)))
"""


def test_valve_node_imports_no_plotting_bags_studies_or_commands():
    done = subprocess.run(
        [sys.executable, '-c', SCRIPT], capture_output=True, text=True, timeout=300, check=True
    )
    loaded = done.stdout.split()
    assert {'valve_sim.ros.valve_node', 'valve_sim.ros.valve_node_main', 'numba'} <= set(loaded)
    unwanted = [
        name
        for name in loaded
        if any(name == prefix or name.startswith(prefix + '.') for prefix in NOT_AT_START)
    ]
    assert unwanted == []
