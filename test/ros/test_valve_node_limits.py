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
valve_node at its physical limits: absurd inputs refused and counted, overpressure held.

One node of its own (namespace /limits) on the wall clock; each test starts it from
the reference parameters at the steady state of 5 L/min and waits only on conditions.
"""

from itertools import takewhile
import math
from pathlib import Path
import re
import time

import pytest
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from valve_harness import running_valve
from valve_sim.core.model import P_S
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import LITRE_PER_MINUTE
from valve_sim.core.steady_state import steady_state


pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures('valve_node_kernels')]

AMBIENT = 101325.0  # [Pa] ambient_pressure default
FLOW = 5.0 * LITRE_PER_MINUTE
NAMESPACE = '/limits'
DOCS = Path(__file__).resolve().parents[2] / 'docs' / 'valve_node.md'
CHAMBER_VOLUMES = ('supply_volume', 'intermediate_volume', 'pilot_volume', 'poppet_chamber_volume')


@pytest.fixture(scope='module')
def node(context, tmp_path_factory):
    """Run the node, inlet_flow subscribed reliably, with its probe: (process, probe, log)."""
    log = tmp_path_factory.mktemp('limits') / 'valve_node.log'
    with running_valve(
        context, log, '-p', 'inlet_flow_reliability:=reliable', namespace=NAMESPACE
    ) as (process, probe):
        yield process, probe, log


@pytest.fixture
def valve(node):
    """Yield the probe, the node restored: reference parameters, 5 L/min, steady state."""
    process, probe, _ = node
    probe.restore(load_parameters().params, FLOW)
    yield probe
    assert process.poll() is None, 'valve_node died'
    assert probe.non_finite == 0, 'a NaN or inf was published'


def call_reset(probe):
    """Call ~/reset; return the response (success or not)."""
    return probe._result(probe.reset_client.call_async(Trigger.Request()))


def reset_ns(response):
    """Return the model time [ns] a successful reset's response names."""
    seconds = re.search(r'model time (\d+)\.(\d{9}) s', response.message)
    return int(seconds[1]) * 1_000_000_000 + int(seconds[2])


def counters(probe, condition=lambda d: True, what='diagnostics'):
    """Wait for a diagnostics report satisfying condition; return it."""
    return probe.wait_for_diagnostics(condition, what)


def common_stamp(probe, from_ns, first=False):
    """
    Return the latest (first) stamp >= from_ns [ns] that every pressure topic has, or None.

    A loaded probe can miss a sample of one topic: the stamps all four have are compared.
    Only the samples from from_ns on are read, newest first (a topic's stamps arrive in
    order), and none while a topic has nothing that late: the waits call this under the
    probe's lock, which its callbacks need too.
    """
    with probe.condition:
        rows_by_topic = list(probe.pressures.values())
        if not all(rows and rows[-1][0] >= from_ns for rows in rows_by_topic):
            return None
        stamps = [
            set(takewhile(lambda stamp: stamp >= from_ns, (s for s, _ in reversed(rows))))
            for rows in rows_by_topic
        ]
    later = set.intersection(*stamps)
    return (min if first else max)(later) if later else None


def pressures_at(probe, stamp):
    """Return {topic: absolute pressure [Pa]} of the samples stamped stamp [ns]."""
    with probe.condition:
        return {
            topic: next(p for s, p in reversed(rows) if s == stamp)
            for topic, rows in probe.pressures.items()
        }


def supply_stamps_and_pressures(probe, start):
    with probe.condition:
        return list(probe.pressures['supply_pressure'][start:])


def test_absurd_flows_are_rejected_counted_and_never_applied(valve):
    """1.0 and 0.05 m^3/s (60 000 and 3 000 L/min into a 20 L/min valve): rejected like NaN."""
    rejected_before = int(counters(valve)['rejected_inputs'])
    start = valve.count()
    for flow in (1.0, 0.05, 1.0, 0.05):
        valve.send_flow(flow)
    report = counters(
        valve, lambda d: int(d['rejected_inputs']) >= rejected_before + 4, 'rejections counted'
    )
    assert int(report['rejected_inputs']) == rejected_before + 4
    valve.wait_for_new_samples(50)
    with valve.condition:
        assert all(q == FLOW for _, q in valve.applied[-50:]), 'the last good flow is held'
    burst = load_parameters().params['burst_pressure']
    assert max(p for _, p in supply_stamps_and_pressures(valve, start)) < burst + AMBIENT
    response = call_reset(valve)
    assert response.success and 'steady state of 8.33333e-05 m^3/s' in response.message
    expected = steady_state(load_parameters().params, FLOW)[P_S]
    assert valve.first_after(reset_ns(response))[1] - AMBIENT == pytest.approx(expected, rel=1e-6)


@pytest.mark.parametrize('flow', [0.05, 1.0])
def test_overpressure_holds_the_state_keeps_the_operators_changes_and_refuses_a_reset(
    valve, flow
):
    """
    A preset change, then a flow the valve cannot relieve: an overpressure alarm, no roll-back.

    max_inlet_flow is lifted above the flow, so the input takes it and burst_pressure
    alone guards the state. The changes were applied well before the failure (beyond
    the trial window), so neither caused it: both stay. The node halts, publishes its
    last good state with ERROR, refuses a reset to the steady state of that flow (an
    impossible state) and resumes on a new valid flow.
    """
    assert valve.set_parameters(preset_pressure=6.5e6)[0].successful
    assert valve.set_parameters(max_inlet_flow=2 * flow)[0].successful
    valve.wait_for_new_samples(100)  # 100 ms: far beyond the 20 ms trial window
    valve.send_flow(flow)
    alarm = counters(valve, lambda d: d['halted'] == 'true', 'the model halted')
    assert alarm['level'] == 2 and 'overpressure' in alarm['message'], alarm['message']
    assert int(alarm['overpressures']) >= 1 and int(alarm['integration_failures']) == 0
    kept = valve.get_parameters('preset_pressure', 'max_inlet_flow')
    assert kept == {
        'preset_pressure': pytest.approx(6.5e6, rel=1e-6),
        'max_inlet_flow': 2 * flow,
    }
    failure = alarm['last_integration_failure']
    failed_ns = round(float(re.search(r'at t = ([0-9.]+) s', failure)[1]) * 1e9)
    rows = valve.pressures['supply_pressure']
    valve.wait_for(  # stamps arrive in order: the 100th newest says it, under the lock
        lambda: len(rows) >= 100 and rows[-100][0] > failed_ns, '100 ticks after the halt'
    )
    held = {p for stamp, p in supply_stamps_and_pressures(valve, 0) if stamp > failed_ns}
    assert len(held) == 1, 'the last good state, published every tick'
    assert held.pop() - AMBIENT <= load_parameters().params['burst_pressure']
    response = call_reset(valve)
    assert not response.success and 'overpressure' in response.message, response.message
    assert f'steady state at {flow:g} m^3/s is refused' in response.message, response.message
    valve.wait_for_new_samples(10)
    after = {p for stamp, p in supply_stamps_and_pressures(valve, 0) if stamp > failed_ns}
    assert len(after) == 1, 'the refused reset kept the state'
    valve.send_flow(FLOW)
    valve.wait_for(lambda: valve.applied[-1][1] == FLOW, 'the model advancing again at 5 L/min')
    counters(valve, lambda d: d['halted'] == 'false', 'the halt reported over')


def test_a_flood_of_mixed_inputs_is_counted_message_by_message(context, valve):
    """
    Every message is accepted or rejected: a reliable publisher, a deep queue.

    The node subscribes reliably here (inlet_flow_reliability): best effort, its
    default, lets the middleware drop messages in a flood before they are counted.
    The flood comes from a node of its own, which nothing spins: the probe's node,
    spun in its thread, is not changed under its executor.
    """
    queue = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    flood = rclpy.create_node('flood', namespace=NAMESPACE, context=context)
    publisher = flood.create_publisher(Float64, 'inlet_flow', queue)
    try:
        valve.wait_for(lambda: publisher.get_subscription_count() > 0, 'flood publisher matched')
        before = counters(valve)
        sent, good = 800, FLOW * 1.01
        for k in range(sent):
            bad = (math.nan, 1.0, -1e-4, math.inf)[k % 4]
            publisher.publish(Float64(data=good if k % 2 else bad))
        report = counters(
            valve,
            lambda d: int(d['accepted_inputs']) + int(d['rejected_inputs'])
            >= int(before['accepted_inputs']) + int(before['rejected_inputs']) + sent,
            'every flooded message counted',
        )
        assert int(report['accepted_inputs']) - int(before['accepted_inputs']) == sent // 2
        assert int(report['rejected_inputs']) - int(before['rejected_inputs']) == sent // 2
        valve.wait_for(lambda: valve.applied[-1][1] == good, 'the last good value applied')
    finally:
        flood.destroy_node()


def test_rejections_under_a_flood_are_warned_at_most_once_a_second(node, valve):
    """A flood of bad flows for about 3 s: the rejection warning stays rate-limited."""
    _, _, log = node
    before = log.read_text().count('inlet_flow message(s) rejected since the last report')
    rejected_before = int(counters(valve)['rejected_inputs'])
    started = time.monotonic()
    while time.monotonic() - started < 3.0:
        for _ in range(100):
            valve.send_flow(math.nan)
    flooded_s = time.monotonic() - started
    counters(
        valve, lambda d: int(d['rejected_inputs']) > rejected_before + 100, 'rejections counted'
    )
    warnings = log.read_text().count('inlet_flow message(s) rejected since the last report')
    assert 1 <= warnings - before <= math.ceil(flooded_s) + 2, log.read_text()[-3000:]


@pytest.mark.parametrize('flow', [1e-15, 1e-12, 1e-9])
def test_tiny_flows_fill_the_closed_valve_for_two_seconds(valve, flow):
    """From the empty valve (reset at 0), a tiny flow fills all chambers together, no failure."""
    valve.send_flow(0.0)
    valve.wait_for(lambda: valve.applied[-1][1] == 0.0, 'flow 0 applied')
    assert call_reset(valve).success
    before = counters(valve)
    valve.send_flow(flow)
    valve.wait_for(lambda: valve.applied[-1][1] == flow, 'the tiny flow applied')
    with valve.condition:
        applied_ns = next(stamp for stamp, q in valve.applied if q == flow)
    valve.wait_for(lambda: common_stamp(valve, applied_ns), 'the pressures of that tick')
    start_ns = common_stamp(valve, applied_ns, first=True)
    start = pressures_at(valve, start_ns)['supply_pressure']
    valve.wait_for(
        lambda: common_stamp(valve, start_ns + 2_000_000_000), '2 s of model time, every pressure'
    )
    stamp = common_stamp(valve, start_ns + 2_000_000_000)
    inner = pressures_at(valve, stamp)
    supply = inner['supply_pressure']
    report = counters(valve)  # sent after that sample
    for key in ('integration_failures', 'overpressures'):
        assert report[key] == before[key], key
    assert report['halted'] == 'false'
    reference = load_parameters().params
    volume = sum(reference[name] for name in CHAMBER_VOLUMES)
    rate = reference['bulk_modulus'] * flow / volume  # [Pa/s] all four chambers fill together
    elapsed = (stamp - start_ns) / 1e9  # [s] of model time between the two samples
    skipped = float(report['skipped_time_s']) - float(before['skipped_time_s'])  # lag, held
    assert start - AMBIENT >= 0.0
    assert rate * (elapsed - skipped) * (1 - 1e-3) - 1e-9 <= supply - start
    assert supply - start <= rate * elapsed * (1 + 1e-3) + 1e-9
    assert all(abs(p - supply) <= 1e-3 * (supply - AMBIENT) + 1e-6 for p in inner.values())


def test_reset_works_at_a_tiny_flow(valve):
    valve.send_flow(1.67e-14)  # 1e-9 L/min
    valve.wait_for(lambda: valve.applied[-1][1] == 1.67e-14, 'the tiny flow applied')
    response = call_reset(valve)
    assert response.success, response.message
    expected = steady_state(load_parameters().params, 1.67e-14)[P_S]
    assert valve.first_after(reset_ns(response))[1] - AMBIENT == pytest.approx(expected, rel=1e-6)


def documented_diagnostics_keys():
    """Return the keys named in the first cell of the key table of docs/valve_node.md."""
    section = DOCS.read_text().split('\n## Diagnostics\n')[1].split('\n## ')[0]
    table = section[section.index('| key | unit | meaning |'):]
    rows = [line for line in table.splitlines() if line.startswith('| `')]
    return {key for row in rows for key in re.findall(r'`([a-z0-9_]+)`', row.split('|')[1])}


def test_the_documentation_names_every_diagnostics_key_and_no_other(valve):
    """docs/valve_node.md's table of diagnostics values is exactly what the node publishes."""
    published = set(counters(valve)) - {'level', 'message', 'name'}  # the status, not values
    assert published == documented_diagnostics_keys()
