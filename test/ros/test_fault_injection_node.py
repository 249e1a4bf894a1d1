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
valve_node's faults and sensors over real DDS, on simulated time (/clock in lockstep).

One node starts with a fault schedule; the tests run in file order on it: the
schedule (compared with the offline run), its parameter values and /parameter_events,
its diagnostics, the overpressure alarm,
sensor noise and bias, dropout, and the parameters' descriptors and checks. An
analyser records meanwhile (fault_status among the rest), so the bag tells when faults
began.
"""

import math
import signal

from diagnostic_msgs.msg import DiagnosticArray
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rcl_interfaces.msg import ParameterEvent
from rclpy.parameter import parameter_value_to_python
from rclpy.qos import qos_profile_parameter_events
from valve_harness import Recorder, running_valve
from valve_sim.core.fault_schedule import load_schedule
from valve_sim.core.model import P_S
from valve_sim.core.sensors import default_settings, read_waveforms
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, simulate
from valve_sim.core.steady_state import steady_state


pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures('valve_node_kernels')]

AMBIENT = 101325.0  # [Pa]
INITIAL_FLOW = 5.0 * LITRE_PER_MINUTE
PERIOD_NS = 1_000_000
NAMESPACE = '/faulty'
# The weakening is small (2 %): a larger one lowers the preset enough that the soft-spring
# main stage rings shut before 0.12 s, and the stuck valve must freeze while it moves.
SCHEDULE = """
events:
  - t: 0.0205
    set:
      fault.damping_orifice_blockage: 0.1
      fault.seat_leakage_diameter: 0.0002
  - t: 0.05
    set: {fault.bearing_coulomb_friction: 5.0, fault.bearing_static_friction: 8.0}
  - t: 0.08
    set:
      fault.pilot_spring_weakening: 0.02
      sensor.supply_pressure.bias: 1000.0
      sensor.supply_pressure.resolution: 10.0
      sensor.supply_pressure.bandwidth: 300.0
  - t: 0.12
    set: {fault.main_valve_stuck: true}
"""
SCHEDULE_END_NS = 200 * PERIOD_NS
HEALTHY_SETTINGS = {
    'fault.damping_orifice_blockage': 0.0,
    'fault.seat_leakage_diameter': 0.0,
    'fault.bearing_coulomb_friction': 0.0,
    'fault.bearing_static_friction': 0.0,
    'fault.pilot_spring_weakening': 0.0,
    'fault.main_valve_stuck': False,
    'sensor.supply_pressure.bias': 0.0,
    'sensor.supply_pressure.resolution': 0.0,
    'sensor.supply_pressure.bandwidth': 0.0,
}


@pytest.fixture(scope='module')
def faulty(context, tmp_path_factory):
    """Start the node with the schedule and an analyser; anchor /clock; yield the probe."""
    folder = tmp_path_factory.mktemp('faulty')
    schedule = folder / 'schedule.yaml'
    schedule.write_text(SCHEDULE)
    recorder = Recorder(folder, NAMESPACE)
    try:
        with running_valve(context, folder / 'valve_node.log', '-p', f'fault_schedule:={schedule}',
                           namespace=NAMESPACE, use_sim_time=True,
                           stop_signal=signal.SIGTERM) as (_, probe):
            recorded = []
            probe.node.create_subscription(DiagnosticArray, '/diagnostics', recorded.append, 10)
            probe.parameter_events = []
            probe.node.create_subscription(ParameterEvent, '/parameter_events',
                                           probe.parameter_events.append,
                                           qos_profile_parameter_events)
            probe.wait_for(lambda: any(
                info.node_namespace == NAMESPACE
                for info in probe.node.get_publishers_info_by_topic('/parameter_events')
            ), "the valve's /parameter_events publisher")

            # The analyser records the valve's (latched) fault status before the schedule starts.
            def fault_status_recorded():
                return any(kv.key == f'messages {NAMESPACE}/fault_status' and int(kv.value) > 0
                           for message in list(recorded) for status in message.status
                           for kv in status.values)

            probe.wait_for(fault_status_recorded, 'the analyser recording fault_status')
            probe.start_ns = probe.start_clock(100 * 1_000_000_000, PERIOD_NS)
            probe.schedule = load_schedule(schedule)
            probe.recorder = recorder
            yield probe
    finally:
        recorder.stop()


def published(probe, topic, since_ns):
    with probe.condition:
        return [(t, p) for t, p in probe.pressures[topic] if t >= since_ns]


def test_a_schedule_gives_the_same_supply_pressure_live_as_offline(faulty, reference):
    faulty.run_until(faulty.start_ns + SCHEDULE_END_NS)
    live = published(faulty, 'supply_pressure', faulty.start_ns)
    assert [t - faulty.start_ns for t, _ in live] == list(range(0, SCHEDULE_END_NS + 1, PERIOD_NS))
    offline = simulate(reference, FlowStep(INITIAL_FLOW, INITIAL_FLOW, 0.0, 0.2),
                       record_interval=1e-3, schedule=faulty.schedule)
    _, readings = read_waveforms(offline, default_settings(), 1e-3, AMBIENT)
    np.testing.assert_allclose([p for _, p in live], readings[:, 0], rtol=1e-9, atol=0.0)
    # The waveform is the faults' doing: it moved, and the main valve froze at 0.12 s.
    assert np.ptp(readings[:, 0]) > 1e5
    with faulty.condition:
        x = {t - faulty.start_ns: row[0] for t, *row in faulty.joints}
    stuck = [x[t] for t in range(120 * PERIOD_NS, SCHEDULE_END_NS + 1, PERIOD_NS)]
    assert len(set(stuck)) == 1 and x[119 * PERIOD_NS] != stuck[0]


def test_scheduled_faults_show_in_the_parameters_and_parameter_events(faulty):
    """Applied directly, not through the parameter service, yet shown as a change is."""
    final = {name: value for event in faulty.schedule for name, value in event.changes.items()}
    assert faulty.get_parameters(*final) == final
    announced = {}  # name: values in the valve's parameter events, in order
    for event in list(faulty.parameter_events):
        if event.node == f'{NAMESPACE}/relief_valve':
            for parameter in event.changed_parameters:
                announced.setdefault(parameter.name, []).append(
                    parameter_value_to_python(parameter.value))
    for name, value in final.items():
        assert announced.get(name, [])[:1] == [value], (name, announced.get(name))


def test_active_faults_show_in_diagnostics_with_their_values(faulty):
    """Each with its value and unit; a fraction has no unit (no stray '1')."""
    values = faulty.wait_for_diagnostics(lambda d: d['level'] >= 1, 'a WARN')
    for text in ('fault.damping_orifice_blockage = 0.1', 'fault.seat_leakage_diameter = 0.0002 m',
                 'fault.bearing_static_friction = 8 N', 'fault.main_valve_stuck',
                 'sensor.supply_pressure.bias = 1000'):
        assert text in values['message'], values['message']
    assert 'fault.damping_orifice_blockage = 0.1 1' not in values['message']
    assert values['level'] == 1 and values['fault_schedule_events_pending'] == '0'


def test_a_fault_driving_p_s_to_the_supply_limit_raises_an_overpressure_alarm(faulty):
    p_s = faulty.latest()[1] - AMBIENT
    limit = p_s + 3e5
    assert faulty.set_parameters(**{'sensor.supply_pressure.bias': 0.0,
                                    'sensor.supply_pressure.resolution': 0.0,
                                    'sensor.supply_pressure.bandwidth': 0.0,
                                    'supply_pressure_limit': limit})[-1].successful
    faulty.send_flow(20.0 * LITRE_PER_MINUTE)
    deadline = faulty.clock_ns + 2000 * PERIOD_NS
    while faulty.latest()[1] - AMBIENT < limit * (1 - 1e-6):
        assert faulty.clock_ns < deadline, 'p_s never reached the limit'
        faulty.tick_at(faulty.clock_ns + PERIOD_NS)
    faulty.run_until(faulty.clock_ns + 50 * PERIOD_NS)  # it keeps running, p_s held
    tail = [p - AMBIENT for _, p in published(faulty, 'supply_pressure', faulty.clock_ns - 40e6)]
    assert len(tail) == 41 and max(tail) == pytest.approx(limit, rel=1e-12)
    values = faulty.wait_for_diagnostics(lambda d: d['level'] == 2, 'an ERROR')
    assert 'OVERPRESSURE' in values['message'] and 'fault.main_valve_stuck' in values['message']
    assert values['overpressure'] == 'true' and values['integration_failures'] == '0'
    assert int(values['overpressure_alarms']) == 1


def test_every_fault_off_and_reset_is_the_healthy_valve_again(faulty, reference):
    assert faulty.set_parameters_atomically(
        **HEALTHY_SETTINGS, supply_pressure_limit=0.0).successful
    faulty.send_flow(INITIAL_FLOW)
    while faulty.applied[-1][1] != INITIAL_FLOW:
        faulty.tick_at(faulty.clock_ns + PERIOD_NS)
    reset_ns = faulty.reset()
    faulty.tick_at(faulty.clock_ns + PERIOD_NS)
    expected = steady_state(reference, INITIAL_FLOW)[P_S] + AMBIENT
    assert faulty.first_after(reset_ns)[1] == pytest.approx(expected, rel=1e-9)
    values = faulty.wait_for_diagnostics(lambda d: d['level'] == 0, 'OK again')
    assert values['faults_active'] == '' and values['overpressure'] == 'false'


def test_sensor_noise_and_bias_are_measured_on_the_published_samples(faulty, reference):
    true = steady_state(reference, INITIAL_FLOW)[P_S] + AMBIENT
    assert faulty.set_parameters(**{'sensor.supply_pressure.noise_std': 2000.0,
                                    'sensor.supply_pressure.bias': 5000.0})[-1].successful
    since = faulty.clock_ns + PERIOD_NS
    faulty.run_until(faulty.clock_ns + 1000 * PERIOD_NS)
    errors = np.array([p for _, p in published(faulty, 'supply_pressure', since)]) - true
    assert len(errors) == 1000
    assert np.mean(errors) == pytest.approx(5000.0, abs=4 * 2000.0 / math.sqrt(1000))
    assert np.std(errors) == pytest.approx(2000.0, rel=0.1)
    assert faulty.set_parameters(**{'sensor.supply_pressure.noise_std': 0.0,
                                    'sensor.supply_pressure.bias': 0.0})[-1].successful


def test_dropout_publishes_nothing_and_the_diagnostics_say_so(faulty):
    assert faulty.set_parameters(**{'sensor.pilot_pressure.dropout': True})[0].successful
    since = faulty.clock_ns + PERIOD_NS
    faulty.run_until(faulty.clock_ns + 20 * PERIOD_NS)
    assert published(faulty, 'pilot_pressure', since) == []
    assert len(published(faulty, 'supply_pressure', since)) == 20
    values = faulty.wait_for_diagnostics(lambda d: d['level'] == 1, 'a WARN')
    assert 'dropout: nothing published on pilot_pressure' in values['message']
    assert values['sensor_dropout'] == 'pilot_pressure'
    assert faulty.set_parameters(**{'sensor.pilot_pressure.dropout': False})[0].successful
    faulty.run_until(faulty.clock_ns + 2 * PERIOD_NS)
    assert len(published(faulty, 'pilot_pressure', since)) == 2


def test_fault_parameters_are_described_and_checked(faulty):
    names = ['fault.bearing_coulomb_friction', 'fault.main_valve_stuck',
             'sensor.supply_pressure.noise_std']
    described = faulty._result(faulty.parameters.describe_parameters(names)).descriptors
    assert 'Coulomb' in described[0].description and described[0].floating_point_range
    assert described[0].floating_point_range[0].to_value == 1000.0
    assert 'stuck' in described[1].description
    assert 'standard deviation' in described[2].description
    refused = faulty.set_parameters(**{'fault.damping_orifice_blockage': 1.5})[0]
    assert not refused.successful and 'fault.damping_orifice_blockage' in refused.reason
    refused = faulty.set_parameters(**{'sensor.pilot_pressure.range_max': 1e5,
                                       'sensor.pilot_pressure.range_min': 2e5})
    assert not refused[1].successful and 'range_max' in refused[1].reason
    assert faulty.set_parameters(**{'sensor.pilot_pressure.range_max': 0.0})[0].successful


def test_the_bag_tells_when_each_fault_began(faulty):
    log = faulty.recorder.stop()
    bag = next(faulty.recorder.folder.glob('*.mcap'))
    began = {}  # setting: model time [ns] from the start at which it first left its default
    with open(bag, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for *_, array in reader.iter_decoded_messages(topics=[f'{NAMESPACE}/fault_status']):
            stamp = array.header.stamp.sec * 1_000_000_000 + array.header.stamp.nanosec
            # named as /diagnostics names the valve's status: node name, no leading slash
            assert array.status[0].name == 'relief_valve: faults'
            assert array.status[0].hardware_id == f'{NAMESPACE}/relief_valve'
            for kv in array.status[0].values:
                if kv.value not in ('0.0', 'false', '-1.0', '0'):
                    began.setdefault(kv.key, stamp - faulty.start_ns)
    assert began['fault.damping_orifice_blockage'] == 21 * PERIOD_NS, log
    assert began['fault.seat_leakage_diameter'] == 21 * PERIOD_NS
    assert began['sensor.supply_pressure.bias'] == 80 * PERIOD_NS
    assert began['fault.main_valve_stuck'] == 120 * PERIOD_NS
