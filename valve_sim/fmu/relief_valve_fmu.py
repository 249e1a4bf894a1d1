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
The module pythonfmu packs as the FMU's entry: the slave of valve_sim, or why it cannot run.

The FMU's binary runs this file from the FMU's resources/ in an embedded Python. It
takes ReliefValve from the valve_sim installed there; where that import fails (no
valve_sim, a missing dependency), ReliefValve is master_logger's stand-in (the FMU
carries a copy of that module), which logs the reason with status error through the
master's logger, whatever its logging setting, and fails fmi2Instantiate.

pythonfmu 0.7's binary runs this file again for each instance with this module's globals
and then releases one reference to them that it never took: the reference taken here
each time keeps the module's namespace alive however many instances come.
"""

import ctypes

ctypes.pythonapi.Py_IncRef(ctypes.py_object(globals()))

try:
    from valve_sim.fmu.relief_valve_slave import ReliefValve  # noqa: F401 (pythonfmu's)
except Exception as error:  # noqa: B902 (whatever stops the import is reported)
    from master_logger import unavailable_slave  # resources/master_logger.py
    from pythonfmu import Fmi2Slave

    ReliefValve = unavailable_slave(error, Fmi2Slave)
