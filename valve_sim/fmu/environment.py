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
The environment a C or C++ master needs to run the FMU on Linux, whatever its shell.

    eval "$(.venv/bin/python -m valve_sim.fmu.environment)"   # then start the master

prints it as shell exports, for the Python that runs this (the one with valve_sim).
The FMU's binary embeds that Python without linking it, and the embedded interpreter
finds its standard library and packages only through these variables:
- LD_PRELOAD: its libpython (else dlopen fails: undefined symbol _Py_NoneStruct);
- PYTHONHOME: its base installation, found whatever python3 is first on PATH (else with
  none of this version first: "No module named 'math'");
- PYTHONPATH: its site-packages and the folder valve_sim is imported from (an editable
  install's clone);
- _ROS_WHEELS_BOOTSTRAP_COMPLETE=1: with the environment's bin/ first on PATH (activated)
  the interpreter takes that environment's site, whose ROS wheels' start-up hook would
  re-execute the process, which an embedded interpreter cannot ("Failed to bootstrap
  ROS environment: execve: argv must not be empty"); the FMU needs no ROS.
"""

import os
from pathlib import Path
import shlex
import site
import sys
import sysconfig


def master_environment():
    """Return {name: value} of the variables a C master needs to load the FMU."""
    import valve_sim

    library = Path(sysconfig.get_config_var('LIBDIR')) / sysconfig.get_config_var('LDLIBRARY')
    paths = [*site.getsitepackages(), str(Path(valve_sim.__file__).parents[1])]
    return {
        'LD_PRELOAD': str(library),
        'PYTHONHOME': sys.base_prefix,
        'PYTHONPATH': os.pathsep.join(dict.fromkeys(paths)),
        '_ROS_WHEELS_BOOTSTRAP_COMPLETE': '1',
    }


if __name__ == '__main__':
    for name, value in master_environment().items():
        print(f'export {name}={shlex.quote(value)}')
