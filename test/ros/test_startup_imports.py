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
valve_node_main, parsing its command line and importing the node's module (as main() does).
Also checked: main() starts the node with automatic garbage collection off and spins it
with the start-up objects frozen, so the housekeeping's collections stay short.
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
import valve_sim.ros.valve_node
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


GC_SCRIPT = """
import gc
import sys
from valve_sim.ros import spinning, valve_node_main

def report(node, executor, stop):
    print(gc.isenabled(), sum(gc.get_count()[:2]), gc.get_freeze_count())

spinning.spin_until = report
sys.exit(valve_node_main.main(['valve_node']))
"""


def test_valve_node_spins_with_its_start_up_objects_frozen():
    done = subprocess.run(
        [sys.executable, '-c', GC_SCRIPT], capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    enabled, young, frozen = done.stdout.split()
    assert enabled == 'False'  # the housekeeping collects, between ticks
    assert int(young) < 1000  # what its gc.collect(1) scans: not the start's 200,000 objects
    assert int(frozen) > 100_000
