#!/usr/bin/env python3
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
The README's two commands, for a machine with nothing but Python 3 and git.

    python3 run.py demo [options]   the main job: valve_node + analyser_node, the paper's step
    python3 run.py test [pytest options] [test paths]   the test suite (the paths only, if given)
    python3 run.py test --quick     the quick tier, for the edit-test loop: the tests of the
                                    core, analysis and recording wings, no ROS node, no colcon,
                                    no slow test (test/conftest.py: quick_tier)
    python3 run.py install          set up .venv, compile the model's kernels and build the
                                    vendored simulation_interfaces, nothing else

Each creates .venv beside this file on first use and installs valve_sim into it
(editable, with its PyPI dependencies and the ROS 2 Jazzy wheels); it reinstalls
when setup.py changes. After installing it compiles the numba kernels into their
cache beside the sources (valve_sim.core.precompile, then the studies' lanes
kernel: studies.runner.compile_lanes), so that valve_node and a study start at once;
`install` does that again (after an edit of valve_sim/core, say). Nothing needs sourcing.
"""

import hashlib
import os
from pathlib import Path
import subprocess
import sys
import venv


ROOT = Path(__file__).resolve().parent
VENV = ROOT / '.venv'
BIN = VENV / 'bin'
STAMP = VENV / 'valve_sim-installed'


def ensure_environment():
    """Create or update .venv if setup.py changed; return whether it (re)installed."""
    wanted = hashlib.sha256((ROOT / 'setup.py').read_bytes()).hexdigest()
    if STAMP.exists() and STAMP.read_text() == wanted:
        return False
    if not (BIN / 'python').exists():
        print(f'run.py: creating virtual environment {VENV}', flush=True)
        venv.EnvBuilder(with_pip=True).create(VENV)
    print(
        'run.py: installing valve_sim and its dependencies (first run only, about a minute)',
        flush=True,
    )
    pip = [str(BIN / 'python'), '-m', 'pip', 'install', '--quiet', '--disable-pip-version-check']
    subprocess.run(pip + ['--upgrade', 'pip'], check=True)
    extras = 'wheels,studies,foxglove,fmu,interfaces,test'
    subprocess.run(pip + ['--editable', f'{ROOT}[{extras}]'], check=True)
    STAMP.write_text(wanted)
    compile_kernels()
    return True


def compile_kernels():
    """Compile the kernels into numba's cache (beside the sources); a failure only warns."""
    print('run.py: compiling the model kernels (about a minute when not cached)', flush=True)
    if subprocess.call([str(BIN / 'python'), '-m', 'valve_sim.core.precompile']) != 0:
        print('run.py: the kernels did not compile; valve_node compiles them at its first start',
              file=sys.stderr)
    lanes = 'from valve_sim.analysis.studies.runner import compile_lanes; compile_lanes()'
    if subprocess.call([str(BIN / 'python'), '-c', lanes]) != 0:  # studies' kernel, once
        print('run.py: the lanes kernel did not compile; the first study compiles it',
              file=sys.stderr)


def build_interfaces():
    """Build the vendored simulation_interfaces into .venv unless there (interfaces/README.md)."""
    if subprocess.call([str(BIN / 'python'), str(ROOT / 'interfaces' / 'build_interfaces.py')]):
        print('run.py: simulation_interfaces not built; valve_simulator is unavailable',
              file=sys.stderr)


def is_test_path(argument):
    """Whether a pytest argument names tests (test/x.py, test/x.py::name) rather than an option."""
    return not argument.startswith('-') and Path(argument.split('::')[0]).exists()


def main(argv):
    if not argv or argv[0] not in ('demo', 'test', 'install'):
        print(__doc__.strip(), file=sys.stderr)
        return 2
    installed = ensure_environment()
    if argv[0] in ('install', 'test'):  # not for the demo, which does not need them
        build_interfaces()
    if argv[0] == 'install':
        if not installed:
            compile_kernels()
        return 0
    env = dict(os.environ, MPLBACKEND='Agg')
    if argv[0] == 'demo':
        command = [str(BIN / 'valve-sim'), 'demo', *argv[1:]]
    else:
        paths = [str(ROOT / 'test')] if not any(map(is_test_path, argv[1:])) else []
        command = [str(BIN / 'python'), '-m', 'pytest', *paths, *argv[1:]]
    return subprocess.call(command, cwd=os.getcwd(), env=env)


if __name__ == '__main__':
    try:
        sys.exit(main(sys.argv[1:]))
    except subprocess.CalledProcessError as error:
        sys.exit(f'run.py: setting up the environment failed: {error}')
