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
Test isolation: a ROS domain of this session's own, discovery on localhost, Ctrl-C delivered.

Every test session claims a ROS_DOMAIN_ID that no other run on this machine holds
(valve_sim.ros.isolation, a lock file per domain) and keeps discovery on localhost,
before anything imports rclpy, so parallel or leftover runs never cross-talk.
Child processes inherit both.

`pytest --quick` (`python3 run.py test --quick`) runs the quick tier only: the test
files of the core, analysis and recording wings (quick_tier), slow tests left out.
"""

import ast
import os
from pathlib import Path
import signal
import time

from valve_sim.ros.isolation import claim_domain

claim_domain(keep_existing=False)
# Children get SIGINT's default action, as from a terminal. Run as a background job,
# this process inherits SIGINT ignored, and so would every node a test starts (Python
# keeps an ignored SIGINT ignored): the tests that send Ctrl-C could not deliver it.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('MPLBACKEND', 'Agg')


import pytest  # noqa: E402, I100  (after the environment is set)

QUICK_WINGS = ('valve_sim.core', 'valve_sim.analysis', 'valve_sim.recording')
# A test file that imports one of these starts nodes or processes, or drives ROS.
NOT_QUICK = ('subprocess', 'valve_harness', 'rclpy')
QUICK_ROS = ('rclpy.serialization',)  # the recording wing's message bytes: no node


def pytest_addoption(parser):
    parser.addoption(
        '--quick',
        action='store_true',
        help='the quick tier: tests of the core, analysis and recording wings, no slow ones',
    )


def quick_tier(path):
    """
    Whether the test file at path is in the quick tier, by what it imports.

    In: it imports valve_sim from the core, analysis and recording wings only, and
    neither rclpy (but its serialization) nor subprocess nor the node harness: no
    ROS node, no colcon, no command in a process of its own.
    """
    imported = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            imported.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            imported.add(node.module)
    ours = [name for name in imported if name.split('.')[0] == 'valve_sim']
    return (
        bool(ours)
        and all(name.startswith(QUICK_WINGS) for name in ours)
        and not any(
            name.split('.')[0] in NOT_QUICK and not name.startswith(QUICK_ROS)
            for name in imported
        )
    )


def pytest_ignore_collect(collection_path, config):
    if (
        config.getoption('quick')
        and collection_path.suffix == '.py'
        and collection_path.name.startswith('test_')
        and not quick_tier(collection_path)
    ):
        return True
    return None


def pytest_collection_modifyitems(config, items):
    if config.getoption('quick'):
        slow = [item for item in items if item.get_closest_marker('slow')]
        config.hook.pytest_deselected(items=slow)
        items[:] = [item for item in items if not item.get_closest_marker('slow')]


@pytest.fixture(scope='module')
def context():
    """Provide an rclpy context of its own for a test module (nodes in the test process)."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    context.try_shutdown()


@pytest.fixture(scope='module')
def node(context):
    """Provide a node of the test process in the module's own rclpy context."""
    import rclpy

    test_node = rclpy.create_node('valve_sim_test', context=context)
    yield test_node
    test_node.destroy_node()


@pytest.fixture(scope='module')
def tick_waveforms():
    """Simulate the paper's step at 0.1 s, 1.15 s long, at 1 kHz: 1151 ticks of 6 messages."""
    from valve_sim.core.parameters import load_parameters
    from valve_sim.core.simulation import FlowStep, simulate

    return simulate(
        load_parameters().params, FlowStep(step_time=0.1, end_time=1.15), record_interval=1e-3
    )


KERNELS_TIMEOUT = 900.0  # [s] a cold compile of valve_node's kernels: ~30 s quiet, minutes loaded


@pytest.fixture(scope='session')
def valve_node_kernels(tmp_path_factory):
    """
    Fill numba's cache with valve_node's kernels, once, before a test starts a node.

    A node compiles them at start when the cache lacks them (a fresh clone, or any edit
    of valve_sim/core): 20-40 s, minutes on a loaded machine, which the node tests'
    waits (valve_harness.TIMEOUT) are not meant to cover. One node started here (in a
    namespace of its own) compiles them; every node after it loads them in a second.
    Asserted: the node logs that it is ready, and exits 0 on SIGINT.
    """
    from valve_harness import start_node, stop_node
    from valve_sim.ros.valve_node import READY_MESSAGE

    log = tmp_path_factory.mktemp('valve_node_kernels') / 'valve_node.log'
    process = start_node(log, '-r', '__ns:=/kernels')
    deadline = time.monotonic() + KERNELS_TIMEOUT
    try:
        while f'{READY_MESSAGE}: ' not in log.read_text():
            assert process.poll() is None, f'valve_node ended:\n{log.read_text()}'
            assert time.monotonic() < deadline, f'no ready line in {KERNELS_TIMEOUT:g} s'
            time.sleep(0.2)  # polls the log for the condition
    finally:
        exit_code = stop_node(process)
    assert exit_code == 0, log.read_text()


@pytest.fixture(scope='session')
def reference():
    """Return the validated parameters of config/reference.yaml."""
    from valve_sim.core.parameters import load_parameters

    return load_parameters().params


@pytest.fixture(scope='session')
def lint_paths():
    """Every source path the ament lint tests check: package, tests, benchmarks, launch."""
    root = Path(__file__).resolve().parents[1]
    names = ['valve_sim', 'test', 'bench', 'launch', 'setup.py', 'run.py']
    return [str(root / name) for name in names if (root / name).exists()]
