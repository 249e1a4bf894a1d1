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
valve_node's logs of what its ticks come to: lag skipped, failures, resumptions, overpressure.

A flapping input can fail every tick and a stalled machine skip lag every tick: lag,
failures and resumptions are logged at most once a second each on the steady clock,
with what was not logged said in the next line; every event is counted in the
diagnostics (node_status.Counters) whether logged or not.
"""

import time

from valve_sim.core.realtime_model import NS_PER_S, Status
from valve_sim.ros.housekeeping import WARNING_INTERVAL_NS
from valve_sim.ros.node_status import Throttle


class TickLogs:
    """
    The rate-limited logs of a ReliefValveNode's ticks, given its logger and counters.

    counters: node_status.Counters (read for the lag in total; overpressure_alarms
    counted here); catch_up_limit_periods: the tick periods of lag a tick integrates.
    """

    def __init__(self, logger, counters, catch_up_limit_periods):
        self._logger = logger
        self._counters = counters
        self._catch_up_limit_periods = catch_up_limit_periods
        self._lag_warnings = Throttle(WARNING_INTERVAL_NS)
        self._failure_logs = Throttle(WARNING_INTERVAL_NS)
        self._resume_logs = Throttle(WARNING_INTERVAL_NS)
        self._failures_unlogged = 0
        self._lag_warned_total_s = 0.0  # skipped_time_s at the last lag warning

    def lag_skipped(self, skipped_ns):
        """Warn of skipped lag at most once a second, with what was skipped since and in total."""
        if not self._lag_warnings.due(time.monotonic_ns()):
            return
        total_s = self._counters.skipped_time_s
        since_s, self._lag_warned_total_s = total_s - self._lag_warned_total_s, total_s
        self._logger.warn(
            f'{skipped_ns / NS_PER_S:g} s of lag skipped (catch-up limit '
            f'{self._catch_up_limit_periods} tick periods); {since_s:g} s skipped '
            f'since the last warning, {total_s:g} s in '
            f'{self._counters.skipped_ticks} tick periods since start'
        )

    def failure(self, outcome, saturated, chamber='supply_pressure'):
        """
        Log a failure the model held its last good state after (an Outcome with an error).

        At most once a second, with how many were not logged; a roll-back and a halt
        (FAILURE) are said too. saturated: the limit [Pa, gauge] the model's chamber (its
        state name) passed, or None.
        """
        if not self._failure_logs.due(time.monotonic_ns()):
            self._failures_unlogged += 1
            return
        unlogged, self._failures_unlogged = self._failures_unlogged, 0
        self._logger.error(f'{outcome.error} The last good state is held.' + (
            f' ({unlogged} more failure(s) since the last report, at most one a second; '
            'all counted in /diagnostics)' if unlogged else ''))
        if outcome.rolled_back:
            self._logger.error(
                'parameters rolled back to the ones in use before the last change, '
                'applied within the trial window before the failure'
            )
        if outcome.status is not Status.FAILURE:
            return
        self._logger.error(
            'the model stops advancing and holds its last good state until a reset, '
            'a new inlet flow or a parameter change'
            + (
                f'; {chamber} is published at burst_pressure = {saturated:g} Pa (gauge), '
                'the limit it passed, the other topics at their last values'
                if saturated is not None
                else ''
            )
        )

    def resumed(self, cause):
        """Say, at most once a second, that a halted model advances again after cause."""
        if self._resume_logs.due(time.monotonic_ns()):
            self._logger.info(f'the model advances again after {cause}')

    def supply_limit(self, reached, was, limit, faults):
        """Count and log p_s reaching supply_pressure_limit [Pa] (faults: a FaultSet), and back."""
        if reached and not was:
            self._counters.overpressure_alarms += 1
            self._logger.error(
                f'OVERPRESSURE: p_s reached supply_pressure_limit = {limit:g} Pa; faults: '
                f'{faults.describe() or "none"}'
            )
        elif was and not reached:
            self._logger.info('p_s back below supply_pressure_limit')
