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
Health counters of valve_node and the /diagnostics status built from them.

Counters run from node start. Each report (1 Hz) also covers the window since the
previous one: the real-time factor (model time advanced / steady time elapsed)
and the tick compute time (p50, p99, max) of the ticks in that window.
"""

from dataclasses import dataclass, fields, replace

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np


NS_PER_S = 1e9
LATE_FRACTION = (
    0.5  # a tick is late if it starts, long if it computes, more than this fraction of a period
)


@dataclass
class Counters:
    """Events since node start or its last ~/restart, as diagnostics report them."""

    ticks: int = 0
    late_ticks: int = 0  # started over LATE_FRACTION of a period after they were due
    long_ticks: int = 0  # computed for over LATE_FRACTION of a period
    missed_ticks: int = 0  # never ran (the next tick integrated their time)
    skipped_ticks: int = 0  # periods not integrated at all: lag beyond the catch-up limit
    skipped_time_s: float = 0.0  # [s] the time not integrated
    accepted_inputs: int = 0  # every inlet_flow message received is accepted ...
    rejected_inputs: int = 0  # ... or rejected
    lost_inputs: int = 0  # sent by one publisher, never received (a gap in its sequence numbers)
    rejected_parameter_changes: int = 0
    integration_failures: int = 0  # numerical divergences
    overpressures: int = 0  # states beyond burst_pressure
    overpressure_alarms: int = 0  # p_s reached supply_pressure_limit
    refused_fault_schedules: int = 0  # schedule files set live that the loader refused
    refused_clock_messages: int = 0  # /clock messages the node cannot represent, ignored
    clock_jumps_back: int = 0  # the clock went back: a new time base
    restarts: int = 0  # ~/restart calls done since the process started (kept by a restart)


class Throttle:
    """
    At most one event per interval_ns [ns] on the steady clock (time.monotonic_ns).

    Timers that fell behind can fire several times in a row: a throttle on the
    steady clock keeps "once a second" to once a second.
    """

    def __init__(self, interval_ns):
        self.interval_ns = interval_ns
        self._last_ns = None

    def due(self, steady_now_ns):
        """Return True, and start a new interval, if the last event is an interval old."""
        if self._last_ns is not None and steady_now_ns - self._last_ns < self.interval_ns:
            return False
        self._last_ns = steady_now_ns
        return True


@dataclass(frozen=True)
class InputReport:
    """The inlet-flow input as diagnostics show it: flow [m^3/s], age [s], stale or not."""

    inlet_flow: float
    seconds_since_input: float
    stale: bool


class NodeStatus:
    """Counters plus the per-window figures of the diagnostics report."""

    def __init__(self, steady_now_ns):
        self.counters = Counters()
        self.last_failure = ''
        self.schedule_refused = ''  # why the last fault schedule set live was refused
        self._reported = Counters()
        self._durations_ns = []
        self._window = (steady_now_ns, None)  # (steady time, model time) at the last report
        self.previous_slot_ns = None  # the slot of the last tick counted by tick_started()

    def restart(self):
        """Count anew, as at node start (valve_node's ~/restart); only restarts goes on."""
        restarts = self.counters.restarts + 1
        for field in fields(Counters):  # in place: the housekeeping holds the counters too
            setattr(self.counters, field.name, field.default)
        self.counters.restarts = restarts
        self._reported = replace(self.counters)
        self.last_failure = self.schedule_refused = ''
        self._durations_ns = []
        self._window = (self._window[0], None)  # no real-time factor across the restart
        self.previous_slot_ns = None

    def tick_started(self, now_ns, newest_slot_ns, period_ns):
        """
        Count a tick that started at now_ns [ns] as late or not, and the slots it missed.

        newest_slot_ns [ns]: the newest slot at or before now_ns, the one an rcl
        timer calls the tick for however many passed; period_ns [ns]: the period.
        The tick was due at the first slot after the previous tick's (the newest
        slot at the first tick, or after previous_slot_ns was set to None): it is
        late if it started over LATE_FRACTION of a period after that slot, so a
        tick after a stall is late, and the slots after its own are missed.
        """
        previous_ns = self.previous_slot_ns
        due_ns = newest_slot_ns if previous_ns is None else previous_ns + period_ns
        self.counters.late_ticks += now_ns - due_ns > LATE_FRACTION * period_ns
        self.counters.missed_ticks += max(round((newest_slot_ns - due_ns) / period_ns), 0)
        self.previous_slot_ns = newest_slot_ns

    def count(self, outcome, period_ns):
        """
        Count what a RealTimeModel.update() came to (its Outcome).

        A failure counts as an overpressure or a divergence; lag skipped counts in
        tick periods of period_ns [ns] (at least one) and in seconds.
        """
        counters = self.counters
        if outcome.error is not None:
            counters.overpressures += outcome.overpressure
            counters.integration_failures += not outcome.overpressure
            self.last_failure = str(outcome.error)
        if outcome.skipped_ns:
            counters.skipped_ticks += max(round(outcome.skipped_ns / period_ns), 1)
            counters.skipped_time_s += outcome.skipped_ns / NS_PER_S

    def tick_done(self, compute_ns, period_ns):
        """
        Count a tick that took compute_ns [ns] of wall time.

        The tick period is period_ns [ns].
        """
        self.counters.ticks += 1
        self.counters.long_ticks += compute_ns > LATE_FRACTION * period_ns
        self._durations_ns.append(compute_ns)

    def report(
        self,
        stamp,
        name,
        hardware_id,
        steady_now_ns,
        model_time_ns,
        inputs,
        settings,
        conditions=(),
        halted=None,
        saturated=None,
        chamber='supply_pressure',
    ):
        """
        Build the DiagnosticArray for the window that ends now; start the next window.

        stamp: header stamp (builtin_interfaces Time); name, hardware_id: the
        status's (valve_sim.ros.diagnostics); model_time_ns: model time [ns] or None
        before the first tick; inputs: InputReport; settings: {name: value} shown as
        they are (units in the names); conditions: [(level, text)] more to report
        (faults, overpressure); halted: why the model stopped advancing, or None
        while it runs; saturated: [Pa gauge] the limit chamber (a state name) is published
        at, or None.
        """
        counters, previous = self.counters, self._reported
        status = DiagnosticStatus(name=name, hardware_id=hardware_id)
        status.level, status.message = self._summary(
            counters, previous, inputs, conditions, halted, saturated, chamber
        )
        values = {
            'real_time_factor': self._real_time_factor(steady_now_ns, model_time_ns),
            **self._compute_times(),
            **{field.name: getattr(counters, field.name) for field in fields(Counters)},
            'last_integration_failure': self.last_failure,
            'halted': halted is not None,
            'inlet_flow_m3_s': inputs.inlet_flow,
            'seconds_since_input': inputs.seconds_since_input,
            'input_stale': inputs.stale,
            'model_time_s': None if model_time_ns is None else model_time_ns / NS_PER_S,
            **settings,
        }
        status.values = [KeyValue(key=key, value=_text(value)) for key, value in values.items()]
        self._reported = replace(counters)
        self._durations_ns = []
        self._window = (steady_now_ns, model_time_ns)
        array = DiagnosticArray(status=[status])
        array.header.stamp = stamp
        return array

    def _summary(
        self, counters, previous, inputs, conditions=(), halted=None, saturated=None,
        chamber='supply_pressure',
    ):
        """
        Return (level, message) of the status.

        ERROR: an overpressure beyond burst_pressure or a divergence in the window, or
        the model halted (state held); WARN: the input is stale, or lag beyond the
        catch-up limit was skipped; OK otherwise (late ticks are named in the message
        but stay OK). conditions [(level, text)] (faults, the supply limit's
        overpressure alarm) come first, at their level.
        """
        problems = [text for _, text in conditions]
        level = max([c[0] for c in conditions], default=DiagnosticStatus.OK)
        overpressures = counters.overpressures - previous.overpressures
        failures = counters.integration_failures - previous.integration_failures
        if overpressures:
            level = DiagnosticStatus.ERROR
            problems.append(
                f'overpressure alarm {overpressures}x, state held: {self.last_failure}'
            )
        if failures:
            level = DiagnosticStatus.ERROR
            problems.append(f'integration diverged {failures}x, state held: {self.last_failure}')
        if halted is not None:
            level = DiagnosticStatus.ERROR
            problems.append(
                'model halted, holding its last good state until a reset, a new inlet flow '
                'or a parameter change'
                + (
                    f'; {chamber} published at burst_pressure = {saturated:g} Pa '
                    '(gauge), the limit it passed'
                    if saturated is not None
                    else ''
                )
            )
        if inputs.stale:
            level = max(level, DiagnosticStatus.WARN)
            problems.append(
                f'input stale: no inlet_flow for {inputs.seconds_since_input:.1f} s, '
                f'holding {inputs.inlet_flow:g} m^3/s'
            )
        skipped, refused, clocks = (
            getattr(counters, name) - getattr(previous, name)
            for name in ('skipped_ticks', 'refused_fault_schedules', 'refused_clock_messages')
        )
        for grown, text in (  # a counter that grew in the window: WARN, with its text
            (skipped, f'{skipped} tick periods skipped (lag beyond the catch-up limit)'),
            (refused, f'fault schedule refused: {self.schedule_refused}'),
            (clocks, f'{clocks} /clock messages ignored (a time the node cannot represent)'),
        ):
            if grown:
                level = max(level, DiagnosticStatus.WARN)
                problems.append(text)
        late = counters.late_ticks - previous.late_ticks
        if late:
            problems.append(f'{late} late ticks')
        return level, '; '.join(problems) or 'running'

    def _real_time_factor(self, steady_now_ns, model_time_ns):
        steady_start, model_start = self._window
        if model_start is None or model_time_ns is None or steady_now_ns <= steady_start:
            return None
        return (model_time_ns - model_start) / (steady_now_ns - steady_start)

    def _compute_times(self):
        """Tick compute time p50, p99 and max of the window [ms] (None without ticks)."""
        names = ('tick_compute_p50_ms', 'tick_compute_p99_ms', 'tick_compute_max_ms')
        if not self._durations_ns:
            return dict.fromkeys(names)
        durations = np.asarray(self._durations_ns) / 1e6
        p50, p99 = np.percentile(durations, [50, 99])
        return dict(zip(names, (p50, p99, durations.max())))


def _text(value):
    """Format a diagnostics value as text: numbers with full precision, booleans as true/false."""
    if isinstance(value, bool):
        return str(value).lower()
    if value is None:
        return ''
    if isinstance(value, float) or isinstance(value, np.floating):
        return repr(float(value))
    return str(value)
