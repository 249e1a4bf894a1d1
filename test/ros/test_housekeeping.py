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

"""valve_node's 1 Hz housekeeping, given what it needs: no node, no spinning."""

import math
from types import SimpleNamespace

import pytest
from rclpy.clock import ClockType
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64
from valve_sim.ros import housekeeping as housekeeping_module
from valve_sim.ros.housekeeping import Housekeeping, WatchedInput
from valve_sim.ros.node_status import Counters
from valve_sim.ros.valve_inputs import InletFlowInput, TankPressureInput


MAX_FLOW = 1.6666666666666667e-3  # [m^3/s] max_inlet_flow of config/reference.yaml


class Logger:
    """rclpy's logger as the housekeeping uses it: the warnings kept."""

    def __init__(self):
        self.warnings = []

    def warn(self, message):
        self.warnings.append(message)


class Publishers:
    """A subscription as the housekeeping asks it: how many publishers it has."""

    def __init__(self, count):
        self.count = count

    def get_publisher_count(self):
        return self.count


class Parts:
    """A Housekeeping with what it needs, and a record of what it did."""

    def __init__(self, monkeypatch, **period):
        self.steady_ns = 10**12
        monkeypatch.setattr(housekeeping_module.time, 'monotonic_ns', lambda: self.steady_ns)
        self.counters = Counters()
        self.inlet = InletFlowInput(1e-4, MAX_FLOW)
        self.tank = TankPressureInput(101325.0, 35e6)
        self.inlet_publishers, self.tank_publishers = Publishers(1), Publishers(2)
        self.clock_guard = SimpleNamespace(refused=0)
        self.done = []  # the chores and input takes, in order
        self.logger = Logger()
        self.timers = []
        self.housekeeping = Housekeeping(
            self.counters,
            (WatchedInput('inlet_flow', self.inlet, self.inlet_publishers,
                          lambda: f'{self.inlet.flow:g} m^3/s'),
             WatchedInput('tank_pressure', self.tank, self.tank_publishers, lambda: '0 Pa')),
            self.clock_guard,
            lambda: self.done.append('take_inputs'),
            (lambda: self.done.append('receive threads'), lambda: self.done.append('report')),
            self.logger,
            lambda period, callback, clock: self.timers.append((period, callback, clock)),
            **period,
        )

    def timer(self, after_s=1.0):
        """Call the 1 Hz timer back, after_s [s] of the steady clock after the last call."""
        self.steady_ns += int(after_s * 1e9)
        self.timers[0][1]()


@pytest.fixture
def parts(monkeypatch):
    return Parts(monkeypatch)


def test_its_timer_is_1_hz_on_the_steady_clock(parts):
    ((period, _, clock),) = parts.timers
    assert period == 1.0 and clock.clock_type == ClockType.STEADY_TIME


def test_a_run_copies_the_counts_notes_single_publishers_and_does_the_chores_in_order(parts):
    for value in (2e-4, math.nan, 3e-4):
        parts.inlet.offer_cdr(serialize_message(Float64(data=value)))
    parts.inlet.lost = 4
    parts.clock_guard.refused = 2
    parts.housekeeping.run()
    counters = parts.counters
    assert (counters.accepted_inputs, counters.rejected_inputs, counters.lost_inputs) == (2, 1, 4)
    assert counters.refused_clock_messages == 2
    assert parts.inlet.single_publisher and not parts.tank.single_publisher  # 1 and 2 publishers
    assert parts.done == ['receive threads', 'report']
    parts.tank_publishers.count = 1
    parts.housekeeping.run()
    assert parts.tank.single_publisher


def test_rejections_are_warned_once_a_second_per_input_with_what_is_held(parts):
    parts.inlet.offer(-1.0)
    parts.inlet.offer(math.inf)
    parts.tank.offer(math.nan)
    parts.housekeeping.run()
    inlet_warning, tank_warning = parts.logger.warnings
    assert inlet_warning.startswith('2 inlet_flow message(s) rejected since the last report '
                                    '(2 since start)')
    assert inlet_warning.endswith('holding 0.0001 m^3/s')
    assert tank_warning.startswith('1 tank_pressure message(s)') and 'holding 0 Pa' in tank_warning
    parts.inlet.offer(-2.0)
    parts.steady_ns += 999_999_999  # within the second: counted, not yet warned
    parts.housekeeping.run()
    assert len(parts.logger.warnings) == 2
    parts.steady_ns += 1
    parts.housekeeping.run()
    assert parts.logger.warnings[2].startswith('1 inlet_flow message(s) rejected since the last '
                                               'report (3 since start)')
    parts.steady_ns += 10**10
    parts.housekeeping.run()  # nothing new rejected: nothing to say
    assert len(parts.logger.warnings) == 3


def test_with_ticks_the_timer_leaves_the_run_to_the_next_tick(parts):
    parts.counters.ticks = 5  # ticks since the last housekeeping
    parts.timer()
    assert parts.done == []  # due: the tick runs it
    parts.housekeeping.after_tick()
    assert parts.done == ['receive threads', 'report']
    parts.housekeeping.after_tick()  # not due again until the timer says so
    assert parts.done == ['receive threads', 'report']


def test_without_ticks_the_timer_takes_the_inputs_and_runs_at_once(parts):
    """None yet, or a paused /clock: no tick would run it, nor take the inputs."""
    parts.timer()
    assert parts.done == ['take_inputs', 'receive threads', 'report']
    parts.counters.ticks = 1
    parts.timer()  # a tick came: due
    parts.timer()  # none for a second since: pending housekeeping runs at once
    assert parts.done.count('report') == 2


def test_timer_calls_queued_back_to_back_count_once(parts):
    parts.timer()
    parts.timer(after_s=0.1)  # a busy executor's backlog
    assert parts.done.count('report') == 1
    parts.timer(after_s=0.5)
    assert parts.done.count('report') == 2


def test_a_shorter_period_times_the_timer_and_its_backlog_rule(monkeypatch):
    """diagnostic_updater.period 0.2 s: a 0.2 s timer; calls closer than 0.1 s count once."""
    parts = Parts(monkeypatch, period=0.2)
    assert parts.timers[0][0] == 0.2
    parts.timer(after_s=0.2)
    parts.timer(after_s=0.05)  # a busy executor's backlog
    assert parts.done.count('report') == 1
    parts.timer(after_s=0.1)
    assert parts.done.count('report') == 2
