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
valve_sim.testing as a user's suite uses it: the pytest fixtures and the context manager.

The tests read as the README's example does; what they assert holds of any valve the
model describes (the state follows every tick; a seized main valve stays put while
the supply relief holds p_s), and the kit's values are the recorded ones.
"""

from pathlib import Path
import shutil

import numpy as np
import pytest
from valve_sim.testing import lockstep_valve


pytest_plugins = ['valve_sim.testing.pytest_plugin']


@pytest.mark.lockstep_valve(parameters={'supply_pressure_limit': '21 MPa'})
def test_the_session_fixture_a_stuck_main_valve_stays_put_and_p_s_meets_the_supply_relief(
        valve_node_kernels, shared_lockstep_valve):
    valve = shared_lockstep_valve
    valve.advance(0.1)
    seized_at = valve.state['main_valve']
    valve.inject('main_valve_stuck')
    valve.set_flow('20 L/min')
    assert valve.advance(0.5) == pytest.approx(0.6)
    assert valve.state['main_valve'] == seized_at
    assert valve.state['supply_pressure'] == pytest.approx(21e6, rel=1e-3)
    assert valve.get_parameters('fault.main_valve_stuck') == {'fault.main_valve_stuck': True}
    with pytest.raises(ValueError, match='no_such_parameter'):
        valve.set_parameters(no_such_parameter=1.0)


def test_the_fixture_records_every_tick_and_measures_the_step(valve_node_kernels,
                                                              lockstep_valve):
    valve = lockstep_valve  # a valve_node of the test's own
    valve.advance(0.25)
    valve.set_flow('20 L/min')
    valve.set_parameters(k_p=valve.get_parameters('pilot_spring_stiffness')[
        'pilot_spring_stiffness'])  # a paper symbol, the same value: nothing changes
    valve.advance(1.05)
    series, step = valve.series, valve.measures(at=0.25)
    latest = valve.state
    assert np.array_equal(series.stamps_ns - series.stamps_ns[0],
                          np.arange(1301) * 1_000_000)  # every tick, t = 0 .. 1.3 s
    assert np.all(series['inlet_flow'][:251] == pytest.approx(5 / 60000))
    assert np.all(series['inlet_flow'][251:] == pytest.approx(20 / 60000))
    assert latest['supply_pressure'] == series['supply_pressure'][-1]
    assert step['direction'] == 1 and step['reasons'] == {}
    peak = series['supply_pressure'][series.window(0.25, 1.3)].max()
    # P_1 from the recorded peak (refined between the ticks around it)
    assert peak <= step['details']['p_1'] <= peak * 1.001
    assert all(np.isfinite(step[name]) for name in ('P_o_percent', 'P_1_percent', 'T_1_ms',
                                                    'r_d', 'T_d_ms', 'T_s_ms'))


def test_the_kit_checks_its_arguments_is_alone_and_a_clock_ahead_of_its_inputs_waits(
        valve_node_kernels):
    """
    Issue 42: one line at the call for each bad argument; a second kit refused.

    Then the race forced: /clock for ten ticks goes out first, their flows 0.3 s later;
    valve_node waits for the inputs stamped for its ticks, so each tick applies its own.
    """
    import time

    from valve_sim.testing import LockstepValve

    with lockstep_valve() as valve:
        for flow, words in [('500 L/min', 'max_inlet_flow'), ('1e6 L/min', 'max_inlet_flow'),
                            (-1, '>= 0'), (float('nan'), 'finite')]:
            with pytest.raises(ValueError, match=words):
                valve.set_flow(flow)
        for seconds in (float('nan'), float('inf'), -0.1, 1e9):
            with pytest.raises(ValueError) as caught:
                valve.advance(seconds)
            assert '\n' not in str(caught.value)
        with pytest.raises(ValueError, match='600000'):
            valve.advance(1e9)
        with pytest.raises(TypeError, match='fault'):
            valve.inject(123)
        with pytest.raises(ValueError, match="no parameter 'nonexist'"):
            valve.get_parameters('nonexist')
        with pytest.raises(RuntimeError, match='already open in this process'):
            LockstepValve()
        assert valve.time == 0.0  # nothing refused moved the valve

        driver = valve._driver
        start, period = driver.clock_ns, driver.period_ns
        ramp = [(5 + k) / 60000 for k in range(10)]  # 5 .. 14 L/min, a tick each
        driver._publish_clock(start + 10 * period)  # the clock first ...
        time.sleep(0.3)
        for k, flow in enumerate(ramp):  # ... then the inputs it needs, and the cover
            driver.set_flow(flow, start + k * period)
        driver.set_flow(ramp[-1], start + 10 * period)
        driver._wait_for(start + 10 * period, 'the ten ticks', ())
        valve._await_row(driver.time_ns)
        assert valve.series['inlet_flow'][1:].tolist() == ramp
    for call in (lambda: valve.advance(0.1), lambda: valve.set_flow(0.0001),
                 lambda: valve.state, lambda: valve.get_parameters('k_p')):
        with pytest.raises(RuntimeError, match='closed'):
            call()


def test_kits_in_processes_sharing_an_environment_get_domains_of_their_own(tmp_path):
    """As pytest-xdist workers: the second process finds the domain held and takes another."""
    import os
    import subprocess
    import sys

    hold = ('import sys, time\nfrom valve_sim.ros.isolation import hold_domain\n'
            'print(hold_domain(), flush=True)\nsys.stdin.read()\n')
    environment = dict(os.environ, ROS_DOMAIN_ID='57')
    first = subprocess.Popen([sys.executable, '-c', hold], env=environment, text=True,
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        held = first.stdout.readline().strip()
        second = subprocess.run([sys.executable, '-c', hold], env=environment, input='',
                                capture_output=True, text=True, timeout=60)
    finally:
        first.communicate('', timeout=60)
    assert held == '57' or held != second.stdout.strip()
    assert second.stdout.strip() != held


def test_a_start_valve_node_refuses_says_its_reason_and_keeps_its_log(valve_node_kernels):
    from valve_sim.testing import LockstepValve

    with pytest.raises(ChildProcessError) as caught:
        LockstepValve(parameters={'publish_rate': 0})
    message = str(caught.value)
    assert 'valve_node refused to start' in message and 'publish_rate' in message
    log = Path(message.rsplit('log kept: ', 1)[1].rstrip(')'))
    assert 'publish_rate' in log.read_text()
    shutil.rmtree(log.parent)  # the kit's temporary folder, kept for the user
