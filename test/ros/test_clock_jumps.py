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
valve_node on a /clock that jumps by whole tick periods (issue 29: lockstep at speed).

tick_times() alone; then one node on /clock, driven by the probe: after the same
parameter change, a jump of TICKS periods publishes the states that TICKS single
periods do (stamps and values equal), its counters count TICKS ticks and nothing
late, missed or skipped; a jump over MAX_TICKS_PER_CLOCK is one state, its lag
counted as before.
"""

import pytest
from valve_harness import PRESSURE_TOPICS, running_valve
from valve_sim.core.simulation import LITRE_PER_MINUTE
from valve_sim.ros.clock_jumps import MAX_TICKS_PER_CLOCK, tick_times


pytestmark = [pytest.mark.timeout(300)]

PERIOD_NS = 1_000_000  # 1 kHz
TICKS = 10  # the lockstep drivers' jump
FLOW = 5.0 * LITRE_PER_MINUTE
TOPICS = (*PRESSURE_TOPICS, 'joint_states', 'applied_inlet_flow')
COUNTERS = ('ticks', 'late_ticks', 'missed_ticks', 'skipped_ticks')


@pytest.mark.parametrize('previous, now, sim_time, expected', [
    (1000, 1000 + 3 * PERIOD_NS, True, [1000 + PERIOD_NS, 1000 + 2 * PERIOD_NS,
                                        1000 + 3 * PERIOD_NS]),
    (0, MAX_TICKS_PER_CLOCK * PERIOD_NS, True, list(range(PERIOD_NS, 101 * PERIOD_NS,
                                                          PERIOD_NS))),
    (0, PERIOD_NS, True, [PERIOD_NS]),  # one period: the one tick
    (0, (MAX_TICKS_PER_CLOCK + 1) * PERIOD_NS, True, [101 * PERIOD_NS]),  # over the limit
    (0, 5 * PERIOD_NS // 2, True, [5 * PERIOD_NS // 2]),  # not whole periods
    (5 * PERIOD_NS, 0, True, [0]),  # back
    (None, 3 * PERIOD_NS, True, [3 * PERIOD_NS]),  # the first tick
    (0, 3 * PERIOD_NS, False, [3 * PERIOD_NS]),  # the system clock: a late tick
])
def test_tick_times_split_only_a_jump_of_a_few_whole_periods_on_clock(previous, now, sim_time,
                                                                      expected):
    assert list(tick_times(previous, now, PERIOD_NS, sim_time)) == expected


@pytest.fixture(scope='module')
def jumping_valve(context, tmp_path_factory, valve_node_kernels, reference):
    """Run a node on /clock in a namespace of its own; yield its probe, the clock started."""
    log = tmp_path_factory.mktemp('clock_jumps') / 'valve_node.log'
    with running_valve(context, log, namespace='/jumps', use_sim_time=True) as (_, probe):
        probe.start_clock(100 * 1_000_000_000, PERIOD_NS)
        yield probe


def states_after(probe, origin_ns):
    """Return {topic: [(stamp - origin_ns, values...)]} of the states after origin_ns."""
    with probe.condition:
        return {topic: [(row[0] - origin_ns, *row[1:]) for row in probe._rows(topic)
                        if row[0] > origin_ns] for topic in TOPICS}


def report_at(probe, time_ns):
    """Wait for a diagnostics report at model time time_ns; return its COUNTERS."""
    report = probe.wait_for_diagnostics(lambda d: d['model_time_s'] == repr(time_ns / 1e9),
                                        f'a report at {time_ns / 1e9} s')
    return {name: int(report[name]) for name in COUNTERS}


def transient(probe, reference, jump):
    """
    Restore, raise the pilot's preload 5 %, then run TICKS periods in one jump or one by one.

    Returns (the states of those periods, the counters before and after).
    """
    preload = reference['pilot_spring_preload']
    probe.restore({'pilot_spring_preload': preload}, FLOW)
    origin_ns = probe.clock_ns
    before = report_at(probe, origin_ns)
    assert all(r.successful for r in probe.set_parameters(pilot_spring_preload=preload * 1.05))
    for tick in ([TICKS] if jump else range(1, TICKS + 1)):
        probe.tick_at(origin_ns + tick * PERIOD_NS)
    probe.wait_for(lambda: all(len(rows) == TICKS
                               for rows in states_after(probe, origin_ns).values()),
                   f'{TICKS} states of every topic')
    return states_after(probe, origin_ns), before, report_at(probe, probe.clock_ns)


def test_a_jump_of_ten_periods_publishes_the_ten_states_of_single_periods(
        jumping_valve, reference):
    singles, _, _ = transient(jumping_valve, reference, jump=False)
    jumped, before, after = transient(jumping_valve, reference, jump=True)
    stamps = [k * PERIOD_NS for k in range(1, TICKS + 1)]
    for topic in TOPICS:
        assert [row[0] for row in jumped[topic]] == stamps, f'{topic}: consecutive stamps'
        assert jumped[topic] == singles[topic], f'{topic}: the same values as single periods'
    supply = [row[1] for row in jumped['supply_pressure']]
    assert len(set(supply)) == TICKS, 'a transient: every state differs from the one before'
    assert {name: after[name] - before[name] for name in COUNTERS} == {
        'ticks': TICKS, 'late_ticks': 0, 'missed_ticks': 0, 'skipped_ticks': 0}


def test_a_jump_over_the_limit_is_one_late_tick_with_its_lag_skipped(jumping_valve, reference):
    probe = jumping_valve
    probe.restore({'pilot_spring_preload': reference['pilot_spring_preload']}, FLOW)
    origin_ns = probe.clock_ns
    before = report_at(probe, origin_ns)
    target_ns = origin_ns + (MAX_TICKS_PER_CLOCK + 1) * PERIOD_NS
    probe.tick_at(target_ns)
    states = states_after(probe, origin_ns)
    assert [row[0] for row in states['supply_pressure']] == [target_ns - origin_ns]
    after = report_at(probe, target_ns)
    assert after['ticks'] - before['ticks'] == 1
    assert after['late_ticks'] - before['late_ticks'] == 1
    assert after['missed_ticks'] - before['missed_ticks'] == MAX_TICKS_PER_CLOCK
    assert after['skipped_ticks'] > before['skipped_ticks']  # beyond the catch-up limit
