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
valve_sim.testing as a user's suite uses it: the pytest fixture and the context manager.

The tests read as the README's example does; what they assert holds of any valve the
model describes (the state follows every tick; a seized main valve stays put while
the supply relief holds p_s), and the kit's values are the recorded ones.
"""

import numpy as np
import pytest
from valve_sim.testing import lockstep_valve


pytest_plugins = ['valve_sim.testing.pytest_plugin']


@pytest.mark.lockstep_valve(parameters={'supply_pressure_limit': '21 MPa'})
def test_the_fixture_a_stuck_main_valve_stays_put_and_p_s_meets_the_supply_relief(
        lockstep_valve, valve_node_kernels):
    valve = lockstep_valve
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


def test_the_context_manager_records_every_tick_and_measures_the_step(valve_node_kernels):
    with lockstep_valve(initial_flow='5 L/min') as valve:
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
