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

"""valve_node's tick logs (TickLogs): at most once a second per kind, the rest counted."""

import pytest
from valve_sim.core.faults import HEALTHY
from valve_sim.core.realtime_model import Outcome, Status
from valve_sim.ros import tick_logs as tick_logs_module
from valve_sim.ros.node_status import Counters
from valve_sim.ros.tick_logs import TickLogs


class Logger:
    """rclpy's logger as TickLogs uses it: every line kept with its severity."""

    def __init__(self):
        self.lines = []

    def __getattr__(self, severity):
        return lambda message: self.lines.append((severity, message))


@pytest.fixture
def steady(monkeypatch):
    """Stand in for the steady clock [ns]: the test moves it."""
    clock = [10**12]
    monkeypatch.setattr(tick_logs_module.time, 'monotonic_ns', lambda: clock[0])
    return clock


@pytest.fixture
def logger():
    return Logger()


@pytest.fixture
def counters():
    return Counters()


@pytest.fixture
def logs(logger, counters, steady):
    return TickLogs(logger, counters, 50)


def test_failures_are_logged_once_a_second_with_how_many_were_not(logs, logger, steady):
    diverged = Outcome(Status.ROLLED_BACK, error=ValueError('diverged.'), rolled_back=True)
    logs.failure(diverged, None)
    assert logger.lines == [
        ('error', 'diverged. The last good state is held.'),
        ('error', 'parameters rolled back to the ones in use before the last change, '
                  'applied within the trial window before the failure'),
    ]
    steady[0] += 500_000_000
    logs.failure(diverged, None)
    logs.failure(diverged, None)
    assert len(logger.lines) == 2  # within the second: counted for the next line
    steady[0] += 500_000_000
    logs.failure(Outcome(Status.FAILURE, error=ValueError('burst.')), 35e6)
    held, halted = logger.lines[2:]
    assert held == ('error', 'burst. The last good state is held. (2 more failure(s) since '
                             'the last report, at most one a second; all counted in /diagnostics)')
    assert halted[1].startswith('the model stops advancing')
    assert 'published at burst_pressure = 3.5e+07 Pa (gauge)' in halted[1]


def test_lag_is_warned_once_a_second_with_the_lag_since_and_in_total(logs, logger, counters,
                                                                     steady):
    counters.skipped_time_s, counters.skipped_ticks = 0.25, 5
    logs.lag_skipped(250_000_000)
    counters.skipped_time_s, counters.skipped_ticks = 0.5, 10
    logs.lag_skipped(250_000_000)  # within the second: not warned
    steady[0] += 10**9
    counters.skipped_time_s, counters.skipped_ticks = 0.75, 15
    logs.lag_skipped(250_000_000)
    assert [message for _, message in logger.lines] == [
        '0.25 s of lag skipped (catch-up limit 50 tick periods); 0.25 s skipped since the '
        'last warning, 0.25 s in 5 tick periods since start',
        '0.25 s of lag skipped (catch-up limit 50 tick periods); 0.5 s skipped since the '
        'last warning, 0.75 s in 15 tick periods since start',
    ]


def test_overpressure_is_counted_once_when_reached_and_its_end_said(logs, logger, counters):
    logs.supply_limit(True, False, 2e7, HEALTHY)
    logs.supply_limit(True, True, 2e7, HEALTHY)  # still there: nothing new
    logs.supply_limit(False, True, 2e7, HEALTHY)
    assert counters.overpressure_alarms == 1
    assert logger.lines == [
        ('error', 'OVERPRESSURE: p_s reached supply_pressure_limit = 2e+07 Pa; faults: none'),
        ('info', 'p_s back below supply_pressure_limit'),
    ]


def test_resumptions_are_said_once_a_second(logs, logger, steady):
    logs.resumed('a new inlet flow')
    logs.resumed('a parameter change')
    steady[0] += 10**9
    logs.resumed('a reset')
    assert [message for _, message in logger.lines] == [
        'the model advances again after a new inlet flow',
        'the model advances again after a reset',
    ]
