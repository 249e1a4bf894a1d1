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
valve_sim, a missing dependency), it raises ImportError with the reason and what to
install or set, which the binary (export_binary) logs with status error, whatever the
master's logging setting, and fmi2Instantiate fails. Standard library only here.
"""

import sys

try:
    from valve_sim.fmu.relief_valve_slave import ReliefValve  # noqa: F401 (pythonfmu's)
except Exception as error:  # noqa: B902 (whatever stops the import is reported)
    raise ImportError(
        f'the valve_sim FMU cannot start: {type(error).__name__}: {error}. The Python '
        f'{sys.version.split()[0]} this FMU runs in ({sys.prefix}) needs valve_sim and its '
        "dependencies: `pip install -e '.[wheels,fmu]'` in a valve_sim clone, or set "
        'PYTHONPATH (and, in a C master, LD_PRELOAD and PYTHONHOME) as docs/fmu.md says: '
        '`python -m valve_sim.fmu.environment` prints them'
    ) from None
