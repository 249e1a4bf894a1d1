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
valve_node's second port over real DDS (issue 30): tank_pressure in, relief_flow out.

A node on simulated time (/clock in lockstep, its own namespace) takes a back-pressure
step as the offline simulation does, refuses and counts bad tank messages, and reports
a silent tank topic stale. Once a tank message came the topic holds the tank pressure
for good, so each test first sends the tank pressure it starts from and resets the
valve there. A wall-clock node started with the tank_pressure parameter shows the
topic taking precedence over it.
"""

import math
import signal
import threading
import time

import numpy as np
import pytest
import rclpy
from sensor_msgs.msg import FluidPressure, JointState
from valve_harness import running_valve, SpinningNode, stamp_ns, TIMEOUT
from valve_sim.core.model import P_S
from valve_sim.core.parameters import config_path, load_parameters
from valve_sim.core.simulation import (
    FlowStep,
    LITRE_PER_MINUTE,
    relief_flows,
    simulate,
    TankPressure,
)
from valve_sim.core.steady_state import steady_state
from valve_sim.ros.spinning import DEFAULT_EXECUTOR, EXECUTORS


pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures('valve_node_kernels')]

AMBIENT = 101325.0  # [Pa] ambient_pressure of config/reference.yaml
FLOW = 5.0 * LITRE_PER_MINUTE
BAR = 1e5
PERIOD_NS = 1_000_000  # 1 kHz
NAMESPACE = '/tank'
RETUNABLE_SETTINGS = ('step_size', 'publish_rate', 'input_timeout', 'ambient_pressure')


class TankPort(SpinningNode):
    """Test-side node in the valve's namespace: sends tank_pressure, records the tank topics."""

    def __init__(self, context, namespace):
        self.node = rclpy.create_node('tank_port', namespace=namespace, context=context)
        self.condition = threading.Condition()
        self.applied = []  # [(stamp_ns, tank pressure [Pa absolute])]
        self.relief = []  # [(stamp_ns, relief flow, main stage, pilot stage, seat leakage)]
        self.node.create_subscription(
            FluidPressure, 'applied_tank_pressure', self._on_applied, 10_000
        )
        self.node.create_subscription(JointState, 'relief_flow', self._on_relief, 10_000)
        self.publisher = self.node.create_publisher(FluidPressure, 'tank_pressure', 100)
        self.spin_in_background(context, EXECUTORS[DEFAULT_EXECUTOR])
        deadline = time.monotonic() + TIMEOUT
        while self.publisher.get_subscription_count() == 0:
            assert time.monotonic() < deadline, 'valve_node never subscribed tank_pressure'
            time.sleep(0.05)

    def _on_applied(self, message):
        with self.condition:
            self.applied.append((stamp_ns(message.header), message.fluid_pressure))

    def _on_relief(self, message):
        assert list(message.name) == ['relief_flow', 'main_stage', 'pilot_stage', 'seat_leakage']
        with self.condition:
            self.relief.append((stamp_ns(message.header), *message.velocity))

    def send(self, absolute):
        """Publish a tank pressure [Pa absolute]."""
        self.publisher.publish(FluidPressure(fluid_pressure=absolute))

    def after(self, rows, time_ns):
        """Return the rows stamped after time_ns [ns]."""
        with self.condition:
            return [row for row in rows if row[0] > time_ns]

    def wait_for(self, condition, what):
        deadline = time.monotonic() + TIMEOUT
        while True:
            with self.condition:
                if condition():
                    return
            assert time.monotonic() < deadline, f'timed out waiting for {what}'
            time.sleep(0.01)


@pytest.fixture(scope='module')
def defaults(reference):
    settings = load_parameters().settings
    return {**reference, **{name: settings[name] for name in RETUNABLE_SETTINGS}}


@pytest.fixture(scope='module')
def sim_tank(context, tmp_path_factory):
    """Run a node on /clock in NAMESPACE; yield (process, probe, tank port)."""
    directory = tmp_path_factory.mktemp('tank_valve')
    with running_valve(
        context,
        directory / 'valve_node.log',
        '--params-file',
        str(config_path('reference.yaml')),
        namespace=NAMESPACE,
        use_sim_time=True,
        stop_signal=signal.SIGTERM,
    ) as (process, probe):
        port = TankPort(context, NAMESPACE)
        try:
            probe.start_clock(100 * 1_000_000_000, PERIOD_NS)
            yield process, probe, port
        finally:
            port.close()


def tank_applied(probe, port, absolute):
    """
    Tick until a tick has applied the tank pressure [Pa absolute]; return that tick's stamp [ns].

    Each tick's applied_tank_pressure is awaited before the next, so the stamp is the
    first one that carries it.
    """
    since_ns = probe.clock_ns
    deadline = time.monotonic() + TIMEOUT
    while True:
        probe.next_tick()
        port.wait_for(
            lambda: port.applied and port.applied[-1][0] >= probe.clock_ns,
            f'applied_tank_pressure stamped {probe.clock_ns} ns',
        )
        carrying = [s for s, p in port.after(port.applied, since_ns) if p == absolute]
        if carrying:
            return carrying[0]
        assert time.monotonic() < deadline, f'the valve never applied {absolute:g} Pa'


def tick_until_reported(probe, condition, what):
    """Tick until a diagnostics report with the tank's values satisfies condition; return it."""
    deadline = time.monotonic() + TIMEOUT

    def reported():
        return [d for d in probe.diagnostics if 'tank_pressure_pa' in d and condition(d)]

    while not probe._wait(reported, 0.05):
        assert time.monotonic() < deadline, f'timed out waiting for {what}'
        probe.next_tick()
    with probe.condition:
        return reported()[-1]


def start_at(sim_tank, defaults, absolute):
    """
    Bring the node to the steady state of FLOW and a tank at absolute [Pa], the defaults set.

    Returns (probe, port, model time of the reset [ns]).
    """
    process, probe, port = sim_tank
    assert process.poll() is None, 'valve_node died'
    port.send(absolute)
    tank_applied(probe, port, absolute)
    restored_ns = probe.restore(defaults, FLOW)
    port.wait_for(
        lambda: port.after(port.applied, restored_ns), 'applied_tank_pressure after the reset'
    )
    assert port.after(port.applied, restored_ns)[0][1] == absolute
    return probe, port, restored_ns


def pressures_after(probe, start_ns):
    """Return {stamp [ns]: supply pressure [Pa, gauge]} published after start_ns."""
    with probe.condition:
        return {s: p - AMBIENT for s, p in probe.pressures['supply_pressure'] if s > start_ns}


def test_a_back_pressure_step_in_the_node_is_the_offline_one(sim_tank, defaults, reference):
    """
    The tank from 1 to 6 bar (gauge) on the topic: p_s, the relief flow as offline.

    The node's samples, 1 ms apart, against `simulate` with the same TankPressure step
    at the tick that applied it: within 0.1 % of the step (the kernels share one code;
    a tick's lag or a gauge/absolute mix-up is 10 to 100 times that).
    """
    low, high = 1 * BAR, 6 * BAR
    probe, port, start_ns = start_at(sim_tank, defaults, AMBIENT + low)
    probe.run_until(start_ns + 20 * PERIOD_NS)
    port.send(AMBIENT + high)
    applied_ns = tank_applied(probe, port, AMBIENT + high)
    probe.run_until(applied_ns + 150 * PERIOD_NS)
    port.wait_for(lambda: port.relief and port.relief[-1][0] >= probe.clock_ns, 'relief_flow')

    step_time = (applied_ns - PERIOD_NS - start_ns) / 1e9  # the tick that applied it began
    end_time = (probe.clock_ns - start_ns) / 1e9
    offline = simulate(
        reference,
        FlowStep(FLOW, FLOW, end_time=end_time + 0.5e-3),
        step_size=defaults['step_size'],
        record_interval=PERIOD_NS / 1e9,
        tank=TankPressure(low, high, step_time=step_time),
    )
    node = pressures_after(probe, start_ns)
    stamps = sorted(node)
    assert stamps == [start_ns + k * PERIOD_NS for k in range(1, len(stamps) + 1)], 'lockstep'
    rows = np.array([(s - start_ns) // PERIOD_NS for s in stamps])
    node_p_s = np.array([node[s] for s in stamps])
    offline_p_s = offline['supply_pressure'][rows]
    np.testing.assert_allclose(node_p_s, offline_p_s, atol=1e-3 * (high - low))
    rise = offline['supply_pressure'][-1] - offline['supply_pressure'][0]
    assert rise == pytest.approx(high - low, rel=1e-3), 'the valve settles one-to-one higher'

    relief = {row[0]: row[1:] for row in port.after(port.relief, start_ns)}
    offline_relief = relief_flows(reference, offline)
    for stamp, row in zip(stamps, rows):
        np.testing.assert_allclose(relief[stamp], offline_relief[row], rtol=1e-3, atol=1e-9)
    assert min(flow for flow, *_ in relief.values()) < 0.5 * FLOW, 'the step held back flow'
    assert relief[stamps[-1]][0] > 0.9 * FLOW, 'relieving the inlet flow again'


def test_bad_tank_messages_are_refused_counted_and_never_applied(sim_tank, defaults):
    """NaN, infinities, a negative absolute and an absurd pressure: counted, 2 bar held."""
    held = AMBIENT + 2 * BAR
    probe, port, start_ns = start_at(sim_tank, defaults, held)
    before = tick_until_reported(probe, lambda d: True, 'a report')
    bad = [math.nan, math.inf, -math.inf, -1.0 * BAR, 1e12, AMBIENT + 35e6]
    for value in bad:
        port.send(value)
    expected = int(before['rejected_tank_pressures']) + len(bad)
    report = tick_until_reported(
        probe, lambda d: int(d['rejected_tank_pressures']) >= expected, 'the rejections counted'
    )
    assert int(report['rejected_tank_pressures']) == expected
    assert float(report['tank_pressure_pa']) == pytest.approx(2 * BAR)
    assert report['tank_pressure_source'] == 'topic'
    applied = port.after(port.applied, start_ns)
    assert applied and all(pressure == held for _, pressure in applied)
    assert all(math.isfinite(p) for p in pressures_after(probe, start_ns).values())


def test_a_silent_tank_topic_is_reported_stale_and_held(sim_tank, defaults):
    """No tank message for longer than input_timeout (model time): stale, the value held."""
    held = AMBIENT + 3 * BAR
    probe, port, start_ns = start_at(sim_tank, defaults, held)
    assert probe.set_parameters(input_timeout=0.02)[0].successful
    probe.run_until(probe.clock_ns + 40 * PERIOD_NS)
    stale = tick_until_reported(probe, lambda d: d['tank_pressure_stale'] == 'true', 'stale')
    assert stale['level'] >= 1 and 'tank_pressure stale' in stale['message']
    assert float(stale['tank_pressure_pa']) == pytest.approx(3 * BAR)
    assert all(p == held for _, p in port.after(port.applied, start_ns))
    with probe.condition:
        start = len(probe.diagnostics)
    deadline = time.monotonic() + TIMEOUT
    while not any(
        d.get('tank_pressure_stale') == 'false' for d in probe.diagnostics[start:]
    ):  # a message every tick, well within input_timeout, until a report shows it fresh
        assert time.monotonic() < deadline, 'the tank never reported fresh again'
        port.send(held)
        probe.next_tick()
        probe._wait(lambda: False, 0.02)


def test_the_topic_takes_precedence_over_the_tank_pressure_parameter(
    context, tmp_path, reference
):
    """Started with tank_pressure = 2 bar it is applied; a message overrides it, a set does not."""
    with running_valve(
        context, tmp_path / 'valve_node.log', '-p', 'tank_pressure:=200000.0',
        namespace='/pressurised',
    ) as (process, probe):
        port = TankPort(context, '/pressurised')
        try:
            port.wait_for(lambda: port.applied, 'applied_tank_pressure')
            assert port.applied[-1][1] == AMBIENT + 2 * BAR
            expected = steady_state(reference, FLOW, tank_pressure=2 * BAR)[P_S]
            assert probe.latest()[1] - AMBIENT == pytest.approx(expected, rel=1e-6)
            port.send(AMBIENT + 4 * BAR)
            port.wait_for(
                lambda: port.applied[-1][1] == AMBIENT + 4 * BAR, 'the topic applied'
            )
            assert probe.set_parameters(tank_pressure=1 * BAR)[0].successful
            sent_ns = port.applied[-1][0]
            port.wait_for(lambda: len(port.after(port.applied, sent_ns)) > 100, 'ticks')
            assert {p for _, p in port.after(port.applied, sent_ns)} == {AMBIENT + 4 * BAR}
        finally:
            port.close()
