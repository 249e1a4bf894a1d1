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
The kit's session fixture (issue 46): one valve_node, a clean valve before each test.

The first test changes every kind of setting a test can (model parameters, the preset,
a fault, a sensor, the tank pressure) and halts the model (a seized main valve with no
supply relief: overpressure); the next must find the start-up valve: every parameter
as at the first test's start, and the same states, bit for bit, as the first test's
first ticks, from the same driver sending the same messages (/clock and the stamped
flow, bytes as published) as a new driver would. A mark's parameters and a refused
restart are checked too. Runs in this order (pytest keeps a module's order; with
xdist, --dist loadfile keeps them together).
"""

import numpy as np
import pytest
from valve_sim.analysis.scenarios.tick_series import SIGNALS
from valve_sim.core.catalogue import VALVE_NODE_SPECS
from valve_sim.testing.lockstep_valve import NoStepError


pytest_plugins = ['valve_sim.testing.pytest_plugin']
NAMES = sorted(VALVE_NODE_SPECS)  # every parameter of the catalogue: model, faults, sensors
FRESH = {}  # what the first test found at its start
SENT = []  # (topic, bytes) the driver published since the test's start


def distinct(sent):
    """Return the messages sent without repeats in a row (a /clock resent under load)."""
    return [message for i, message in enumerate(sent) if i == 0 or message != sent[i - 1]]


@pytest.fixture(autouse=True)
def sent_in_test():
    """Forget the messages sent before the test (its valve's restart is the test's)."""
    SENT.clear()


@pytest.fixture(scope='module')
def lockstep_valve_session(tmp_path_factory):
    """
    Give the module the plugin's session valve, stopped at the module's end.

    The override the plugin's docs offer: the suite's later tests start valve_nodes of
    their own in this session's ROS domain, and a session valve_node left running would
    answer their /clock too.
    """
    from rclpy.publisher import Publisher
    from valve_sim.testing.lockstep_valve import LockstepValve

    publish = Publisher.publish
    def record(publisher, message):  # the driver's raw messages (/clock, the stamped flow)
        if isinstance(message, bytes):
            SENT.append((publisher.topic_name, message))
        publish(publisher, message)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Publisher, 'publish', record)
        valve = LockstepValve(folder=tmp_path_factory.mktemp('lockstep_valve_session'))
        FRESH['driver'], FRESH['new driver sent'] = valve._driver, distinct(SENT)
        yield valve
        valve.close()


def first_ticks(valve):
    """Return the valve's parameters and its states over its first 50 ms at 5 -> 12 L/min."""
    valve.advance(0.01)
    valve.set_flow('12 L/min')
    valve.advance(0.04)
    series = valve.series
    return valve.get_parameters(*NAMES), {'stamps': series.stamps_ns,
                                          **{name: series[name] for name in SIGNALS}}


def test_a_test_that_changes_every_kind_of_setting_and_halts_the_model(
        valve_node_kernels, shared_lockstep_valve):
    valve = shared_lockstep_valve
    FRESH['parameters'], FRESH['series'] = first_ticks(valve)
    FRESH['sent'] = distinct(SENT)
    # the start after the restart: as a new driver's (the first flow and /clock)
    assert FRESH['sent'][:2] == FRESH['new driver sent'] and len(FRESH['sent']) > 2
    valve.set_parameters(preset_pressure='6 MPa', k_p=9000.0, tank_pressure='2 bar',
                         burst_pressure='10 MPa')
    valve.set_parameters({'sensor.supply_pressure.bias': 1e5, 'sensor.noise_seed': 7})
    valve.inject('damping_orifice_blockage', 0.3)
    valve.inject('main_valve_stuck')
    valve.set_flow('30 L/min')  # seized, no supply relief: p_s climbs past burst
    valve.advance(0.3)
    held = valve.series['supply_pressure'][-100:]  # halted: the last good state, held
    assert 9e6 < held[0] <= 10e6 + 1e5 and (held == held[0]).all(), held
    changed = valve.get_parameters('preset_pressure', 'fault.main_valve_stuck',
                                   'sensor.supply_pressure.bias', 'tank_pressure')
    assert changed['fault.main_valve_stuck'] is True and changed['preset_pressure'] == 6e6


def test_the_next_test_finds_the_start_up_valve(shared_lockstep_valve):
    assert FRESH, 'runs after the test before it'
    parameters, series = first_ticks(shared_lockstep_valve)
    assert shared_lockstep_valve._driver is FRESH['driver']  # no new driver, no discovery
    assert distinct(SENT) == FRESH['sent']
    assert parameters == FRESH['parameters']
    assert len(series['stamps']) == 51
    for name, values in series.items():  # bit for bit: the same states at the same stamps
        assert np.array_equal(values, FRESH['series'][name], equal_nan=True), name


@pytest.mark.lockstep_valve(parameters={'preset_pressure': '5 MPa'}, initial_flow='10 L/min')
def test_a_mark_sets_the_start_of_the_shared_valve(shared_lockstep_valve):
    valve = shared_lockstep_valve
    assert valve.time == 0.0 and len(valve.series) == 1
    assert valve.get_parameters('preset_pressure') == {'preset_pressure': 5e6}
    assert valve.state['inlet_flow'] == pytest.approx(10 / 60_000)
    assert 4.9e6 < valve.state['supply_pressure'] < 5.2e6
    with pytest.raises(NoStepError, match='no step at 0.1 s'):
        valve.measures(at=0.1)
    with pytest.raises(ValueError, match='restart refused, nothing changed: preset pressure'):
        valve.restart({'preset_pressure': '1 kPa'})
    assert valve.get_parameters('preset_pressure') == {'preset_pressure': 5e6}
    assert valve.advance(0.01) == pytest.approx(0.01)
