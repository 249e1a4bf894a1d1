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
The package as a ROS user installs it: a plain `colcon build`, then the install space alone.

colcon builds a copy of the source tree in a temporary workspace (no
--symlink-install); the installed valve_node is started from an empty folder,
with the environment that sourcing install/setup.bash gives (AMENT_PREFIX_PATH,
PYTHONPATH), and must publish. The build compiled its kernels into numba's cache
beside the installed sources (setup.py, valve_sim.core.precompile): the first start
finds every kernel there and writes none. The launch file, LICENSE and rosdep keys
are checked against the same install. A `colcon build --symlink-install` (setup.py
develop) of another copy must likewise compile the kernels its installed node loads.
"""

import ast
import os
from pathlib import Path
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ElementTree

import pytest
from valve_harness import Probe, stop_node
from valve_sim.ros.analyser_node import parameter_names


pytestmark = pytest.mark.timeout(1200)

REPO = Path(__file__).resolve().parents[2]
START_TIMEOUT = 240.0  # [s] a cold kernel compile on a loaded 2-core machine
BUILD_TIMEOUT = 900  # [s] colcon build, the kernels' compile included, on a loaded machine
NOT_SOURCES = ('.venv', '.git', '__pycache__', 'build', 'install', 'log', '*.egg-info', 'demo_*')
# The rosdep keys of package.xml and the file of ros/rosdistro that defines each (checked at
# rosdistro commit 8468e88, 2026-08-22). A new dependency needs its key checked and added here.
ROSDEP_KEYS = {
    **dict.fromkeys(
        [
            'rclpy',
            'std_msgs',
            'sensor_msgs',
            'diagnostic_msgs',
            'std_srvs',
            'rcl_interfaces',
            'builtin_interfaces',
            'rosgraph_msgs',
            'lifecycle_msgs',
            'simulation_interfaces',
            'ament_index_python',
            'launch',
            'launch_ros',
            'ament_flake8',
            'ament_pep257',
            'ament_copyright',
        ],
        'jazzy/distribution.yaml',
    ),
    **dict.fromkeys(
        [
            'python3-numpy',
            'python3-scipy',
            'python3-matplotlib',
            'python3-yaml',
            'python3-numba',
            'mcap-ros2-support',
            'python3-pytest',
            'python3-pytest-timeout',
            'python3-psutil',
            'python3-rosbags-pip',
        ],
        'rosdep/python.yaml',
    ),
}


@pytest.fixture(scope='module')
def install(tmp_path_factory):
    """Build a copy of the package with plain `colcon build`; returns install/valve_sim."""
    return colcon_build(tmp_path_factory.mktemp('colcon_ws'))


def colcon_build(workspace, *options, **environment):
    """Run `colcon build OPTIONS` on a copy of the package in workspace; return its prefix."""
    shutil.copytree(
        REPO, workspace / 'src' / 'valve_sim', ignore=shutil.ignore_patterns(*NOT_SOURCES)
    )
    colcon = Path(sys.executable).parent / 'colcon'
    assert colcon.exists(), f'{colcon} missing: colcon-core is a test dependency (setup.py)'
    result = subprocess.run(
        [str(colcon), 'build', *options],
        cwd=workspace,
        capture_output=True,
        text=True,
        timeout=BUILD_TIMEOUT,
        env=dict(
            plain_environment(),
            PATH=f'{colcon.parent}{os.pathsep}{os.environ["PATH"]}',
            **environment,
        ),
    )
    assert result.returncode == 0, result.stdout + result.stderr
    return workspace / 'install' / 'valve_sim'


def plain_environment():
    """Return this environment without a numba cache folder of its own (a user's shell)."""
    return {key: value for key, value in os.environ.items() if key != 'NUMBA_CACHE_DIR'}


def sourced(prefix):
    """
    Return the environment `source install/setup.bash` gives for this one package.

    As colcon's setup scripts do, it follows the package's hooks (share/valve_sim/
    package.dsv): AMENT_PREFIX_PATH and PYTHONPATH, with colcon's build folder first
    on PYTHONPATH after a --symlink-install build.
    """
    paths = {}
    hook_paths(prefix / 'share' / 'valve_sim' / 'package.dsv', prefix, paths)
    return dict(
        plain_environment(),
        **{name: os.pathsep.join(values) for name, values in paths.items()},
        PYTHONUNBUFFERED='1',
    )


def hook_paths(hook, prefix, paths):
    """Prepend the paths a colcon hook file (.dsv) and those it sources set: {variable: [path]}."""
    for line in hook.read_text().splitlines():
        kind, *arguments = line.split(';')
        if kind == 'source' and arguments[0].endswith('.dsv'):
            hook_paths(prefix / arguments[0], prefix, paths)
        elif kind == 'prepend-non-duplicate':
            name, value = arguments
            paths.setdefault(name, []).insert(0, str(prefix / value))  # an absolute value stays


def test_the_install_space_has_its_code_config_and_launch_file(install):
    code = (
        'from valve_sim.core.parameters import config_path; '
        "import valve_sim; print(valve_sim.__file__); print(config_path('reference.yaml'))"
    )
    module, config = subprocess.run(
        [sys.executable, '-c', code],
        env=sourced(install),
        cwd=install.parent.parent,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    assert Path(module).is_relative_to(install), 'the installed code, not the source tree'
    fmu_binary_sources = Path(module).parent / 'fmu' / '_pythonfmu_export'  # valve-sim fmu builds
    assert (fmu_binary_sources / 'pythonfmu' / 'fmi2.cpp').is_file()
    assert (fmu_binary_sources / 'LICENSE').is_file()
    assert Path(config) == install / 'share' / 'valve_sim' / 'config' / 'reference.yaml'
    share = install / 'share' / 'valve_sim'
    for name in ('package.xml', 'LICENSE', 'config/table2.yaml', 'launch/valve_sim.launch.py',
                 'scenarios/paper_step.yaml', 'scenarios/stuck_main_valve.yaml'):
        assert (share / name).is_file(), name


def kernel_cache(folder):
    """Return {path: (size, mtime_ns)} of numba's cache files in folder."""
    return {
        path: (path.stat().st_size, path.stat().st_mtime_ns)
        for path in folder.rglob('*.nb[ic]')
    }


def test_installed_valve_node_starts_from_another_folder_and_publishes(
    install, context, tmp_path
):
    built = kernel_cache(install)
    core = next(install.glob('lib/python*/site-packages/valve_sim/core'))
    assert {path.parent for path in built} == {core / '__pycache__'}, 'the build compiled them'
    assert any(path.name.startswith('integrator.rk4_steps-') for path in built)
    start_installed_node(install, sourced(install), context, tmp_path, '/installed')
    assert kernel_cache(install) == built, 'the first start compiled (and cached) kernels'


def test_symlink_install_compiles_the_kernels_its_valve_node_loads(context, tmp_path):
    """--symlink-install runs setup.py develop: the node imports the sources via build/."""
    cache = tmp_path / 'numba_cache'  # empty: not the caches beside this checkout's sources
    cache.mkdir()
    install = colcon_build(
        tmp_path / 'colcon_ws', '--symlink-install', NUMBA_CACHE_DIR=str(cache)
    )
    built = kernel_cache(cache)
    assert any(path.name.startswith('integrator.rk4_steps-') for path in built), (
        'the build compiled the kernels'
    )
    run = tmp_path / 'run'
    run.mkdir()
    environment = dict(sourced(install), NUMBA_CACHE_DIR=str(cache))
    start_installed_node(install, environment, context, run, '/symlinked')
    assert kernel_cache(cache) == built, 'the first start compiled (and cached) kernels'


def start_installed_node(install, environment, context, folder, namespace,
                         program='valve_node', options=()):
    """Start the installed valve_node (or program) in folder; check its states and clean stop."""
    log_path = folder / f'{program}.log'
    with open(log_path, 'w') as log:
        process = subprocess.Popen(
            [str(install / 'lib' / 'valve_sim' / program), *options, '--ros-args', '-r',
             f'__ns:={namespace}'],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=environment,
            cwd=folder,
        )
    probe = Probe(context, namespace)
    try:
        probe.wait_for(
            lambda: probe.pressures['supply_pressure'] or process.poll() is not None,
            'supply_pressure from the installed valve_node',
            timeout=START_TIMEOUT,
        )
        assert process.poll() is None, log_path.read_text()
        probe.wait_for_new_samples(100)
        assert probe.non_finite == 0
        assert 7e6 < probe.latest()[1] < 7.2e6  # [Pa abs] 5 L/min: 7 MPa gauge
    finally:
        probe.close()
        exit_code = stop_node(process)
    assert exit_code == 0, log_path.read_text()
    assert 'ready: model kernels compiled or loaded' in log_path.read_text()


def test_installed_managed_valve_node_autostarts_and_valve_simulator_answers_help(
    install, context, tmp_path
):
    start_installed_node(install, sourced(install), context, tmp_path, '/installed_managed',
                         'managed_valve_node', ['--autostart'])
    result = subprocess.run(
        [str(install / 'lib' / 'valve_sim' / 'valve_simulator'), '--help'],
        env=sourced(install), cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert 'usage: valve_simulator' in result.stdout


def test_installed_analyser_help_exits_0_and_writes_nothing(install, tmp_path):
    result = subprocess.run(
        [str(install / 'lib' / 'valve_sim' / 'analyser_node'), '--help'],
        env=sourced(install),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stderr
    assert 'usage: analyser_node' in result.stdout and 'output_dir' in result.stdout
    assert list(tmp_path.iterdir()) == [], 'nothing recorded'


def launch_calls(tree, name):
    """Yield the keyword dicts of every call of name (e.g. Node) in a parsed file."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and name in (
            getattr(node.func, 'id', None),
            getattr(node.func, 'attr', None),
        ):
            yield {keyword.arg: keyword.value for keyword in node.keywords}, node.args


def test_launch_file_compiles_and_names_only_what_is_installed(install):
    """launch_ros cannot be installed here: the file compiles and all it names exists."""
    path = install / 'share' / 'valve_sim' / 'launch' / 'valve_sim.launch.py'
    source = path.read_text()
    compile(source, str(path), 'exec')
    tree = ast.parse(source)
    constants = {
        target.id: statement.value.value
        for statement in tree.body
        if isinstance(statement, ast.Assign) and isinstance(statement.value, ast.Constant)
        for target in statement.targets
    }
    declared = {args[0].value for _, args in launch_calls(tree, 'DeclareLaunchArgument')}
    assert declared == {'params_file', 'namespace', 'use_sim_time', 'output_dir', 'managed',
                        'autostart'}
    used = {args[0].value for _, args in launch_calls(tree, 'LaunchConfiguration')}
    assert used <= declared
    joined = [
        [arg.value for arg in args if isinstance(arg, ast.Constant)]
        for _, args in launch_calls(tree, 'join')
    ]
    assert joined == [['config', 'reference.yaml']]
    assert (install / 'share' / 'valve_sim' / 'config' / 'reference.yaml').is_file()
    node_parameters = {
        'valve_node': {'use_sim_time'},
        'managed_valve_node': {'use_sim_time'},
        'analyser_node': set(parameter_names()) | {'use_sim_time'},
    }
    assigned = {  # name = value inside the function: the valve's parameter list
        target.id: statement.value
        for statement in ast.walk(tree)
        if isinstance(statement, ast.Assign)
        for target in statement.targets
        if isinstance(target, ast.Name)
    }
    nodes = list(launch_calls(tree, 'Node')) + list(launch_calls(tree, 'LifecycleNode'))
    assert len(nodes) == 3
    for keywords, _ in nodes:
        assert constants[keywords['package'].id] == 'valve_sim'
        executable = keywords['executable'].value
        assert os.access(install / 'lib' / 'valve_sim' / executable, os.X_OK), executable
        parameters = keywords['parameters']
        parameters = assigned.get(getattr(parameters, 'id', None), parameters)
        names = {
            key.value
            for element in parameters.elts
            if isinstance(element, ast.Dict)
            for key in element.keys
        }
        assert names <= node_parameters[executable], (executable, names)


def test_license_and_rosdep_keys():
    license_text = (REPO / 'LICENSE').read_text()
    assert 'Apache License' in license_text and 'Version 2.0, January 2004' in license_text
    package = ElementTree.parse(REPO / 'package.xml').getroot()
    assert package.findtext('license') == 'Apache-2.0'
    keys = [
        element.text
        for element in package
        if element.tag.endswith('depend') and element.tag != 'buildtool_depend'
    ]
    assert keys and sorted(set(keys)) == sorted(keys), 'no key twice'
    unchecked = [key for key in keys if key not in ROSDEP_KEYS]
    assert unchecked == [], f'rosdep keys not checked against rosdistro: {unchecked}'


def test_setup_py_passes_setuptools_no_option_it_warns_about():
    """tests_require: deprecated, and each pip install warned of it (three times)."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    (setup_call,) = [keywords for keywords, _ in launch_calls(tree, 'setup')]
    assert 'tests_require' not in setup_call and 'test_suite' not in setup_call


def test_valve_node_help_names_the_layout_file_this_install_has(install, tmp_path):
    """--foxglove's help gives the path of the layout where this installation keeps it."""
    result = subprocess.run(
        [str(install / 'lib' / 'valve_sim' / 'valve_node'), '--help'],
        env=sourced(install), cwd=tmp_path, capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stderr
    shown = result.stdout.split('the layout to open:', 1)[1].split('. On a ROS', 1)[0]
    path = Path(''.join(shown.split()))  # argparse wraps it; it holds no space here
    assert path.is_file() and path.name == 'valve_layout.json'
    assert install in path.parents  # the install space's own copy, not the source tree's
