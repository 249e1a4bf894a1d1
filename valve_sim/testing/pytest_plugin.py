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
The pytest fixture `lockstep_valve`: a LockstepValve per test, its log in the test's tmp_path.

In the root conftest.py of a suite:  pytest_plugins = ['valve_sim.testing.pytest_plugin']
(in a test module it works too, but pytest reads the module's marks before it loads
the plugin, and warns that the mark is unknown).

    @pytest.mark.lockstep_valve(parameters={'supply_pressure_limit': '21 MPa'})
    def test_relief(lockstep_valve):
        lockstep_valve.set_flow('20 L/min')
        lockstep_valve.advance(0.5)
        assert lockstep_valve.state['supply_pressure'] < 7.5e6

The mark's keywords are LockstepValve's (parameters, initial_flow, params_file,
namespace); without it, the reference valve at 5 L/min.

`shared_lockstep_valve` is the same valve for a test, from ONE valve_node per pytest
session (per xdist worker: each is a session), restarted in place before each test
(LockstepValve.restart: valve_node's ~/restart): every parameter at its start-up value
with the mark's parameters over it, no fault, sensors, preset and tank as those say,
the exact steady state of the mark's initial_flow, time from 0, no state kept; the same
driver goes on (Lockstep.restart): a few milliseconds a test against seconds for a
process's start (bench/bench_suite.py). The mark takes parameters
and initial_flow; a params_file or namespace is the session's (the
`lockstep_valve_session` fixture, which a conftest.py may override). The session's
valve_node runs in a ROS domain of its own (LockstepValve apart=True), so it never
answers the /clock of the suite's other runs (a lockstep_valve per test, a scenario
run); ROS_DOMAIN_ID is its domain during a test that uses it.
"""

import pytest


def pytest_configure(config):
    config.addinivalue_line('markers', 'lockstep_valve(**options): how the lockstep_valve '
                            'fixture starts valve_node (valve_sim.testing.LockstepValve)')


@pytest.fixture(scope='session')
def lockstep_valve_session(tmp_path_factory):
    """One valve_node in lockstep for the session, in a domain apart; stopped at its end."""
    from valve_sim.testing.lockstep_valve import LockstepValve

    valve = LockstepValve(folder=tmp_path_factory.mktemp('lockstep_valve_session'),
                          apart=True)
    yield valve
    valve.close()


@pytest.fixture
def shared_lockstep_valve(request, lockstep_valve_session, monkeypatch):
    """
    Restart the session's valve_node for this test as the lockstep_valve mark says.

    ROS_DOMAIN_ID is the valve's for the test: a node it creates (a controller under
    test) talks to the valve.
    """
    mark = request.node.get_closest_marker('lockstep_valve')
    options = dict(mark.kwargs) if mark else {}
    unknown = sorted(set(options) - {'parameters', 'initial_flow'})
    if unknown:
        pytest.fail(f"shared_lockstep_valve: the session's valve_node has its {unknown} "
                    'already; use the lockstep_valve fixture for them', pytrace=False)
    lockstep_valve_session.restart(**options)
    monkeypatch.setenv('ROS_DOMAIN_ID', str(lockstep_valve_session.domain))
    return lockstep_valve_session


@pytest.fixture
def lockstep_valve(request, tmp_path):
    """Start a valve_node in lockstep for one test (a LockstepValve); stop it after."""
    from valve_sim.testing.lockstep_valve import LockstepValve

    mark = request.node.get_closest_marker('lockstep_valve')
    options = dict(mark.kwargs) if mark else {}
    valve = LockstepValve(folder=tmp_path / 'lockstep_valve', **options)
    yield valve
    valve.close()
