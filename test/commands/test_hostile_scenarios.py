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
A check never passes without data (issue 43, section 2).

`scenario check` (load_scenario) refuses every time and window outside the run:
inverted windows, windows past the end, negative bounds, changes and events after the
duration. At run time a check whose window holds no sample fails with that reason in
every kind, no_alarm included.
"""

import re

import numpy as np
import pytest
from valve_sim.analysis.scenarios.bench_scenario import load_scenario
from valve_sim.analysis.scenarios.expectations import evaluate, parse_expectations
from valve_sim.analysis.scenarios.tick_series import TickSeries
from valve_sim.core.errors import InputFileError


BASE = ('duration: 0.8\ninputs:\n  inlet_flow: {initial: 5 L/min, changes: [%s]}\n'
        '%sexpect:\n  - %s\n')
REFUSED = [  # (changes, events, expectation, the key named)
    ('', '', 'no_alarm: {from: 0.8, to: 0.3}', 'inverted'),
    ('', '', 'no_alarm: {from: 5, to: 10}', 'no_alarm.from'),
    ('', '', 'never_above: {signal: supply_pressure, value: 8 MPa, from: 0.5, to: 10}',
     'never_above.to'),
    ('', '', 'never_below: {signal: supply_pressure, value: 1 MPa, from: -1}', 'never_below.from'),
    ('', '', 'alarm: {after: 0.3, within: -1}', 'alarm.within'),
    ('', '', 'alarm: {after: 2, within: 0.1}', 'alarm.after'),
    ('', '', 'steady: {signal: supply_pressure, flow: 5 L/min, max: 8 MPa, window: -1}',
     'steady.window'),
    ('', '', 'steady: {signal: supply_pressure, flow: 5 L/min, max: 8 MPa, window: 2}',
     'steady.window'),
    ('', '', 'measures: {at: 3, T_s_ms: {max: 600}}', 'measures.at'),
    ('{at: 0.9, step: 20 L/min}', '', 'no_alarm: {}', 'changes[0].at'),
    ('', 'events: [{t: 1.5, set: {fault.main_valve_stuck: true}}]\n', 'no_alarm: {}', 'events'),
]


@pytest.mark.parametrize('changes, events, expectation, key', REFUSED)
def test_scenario_check_refuses_times_outside_the_run(tmp_path, changes, events, expectation,
                                                      key):
    path = tmp_path / 'hostile.yaml'
    path.write_text(BASE % (changes, events, expectation))
    with pytest.raises(InputFileError, match=re.escape(key)) as refused:
        load_scenario(path)
    assert '\n' not in str(refused.value)


def test_times_at_the_edges_of_the_run_are_accepted(tmp_path):
    path = tmp_path / 'edges.yaml'
    path.write_text(BASE % ('{at: 0.8, step: 6 L/min}', 'events: [{t: 0.8, set: '
                            '{fault.main_valve_stuck: true}}]\n', 'no_alarm: {from: 0, to: 0.8}'))
    assert load_scenario(path).duration == 0.8


def series_of_a_run(end_s=0.8, alarm_at=0.61):
    """0 .. end_s at 1 kHz; p_s at its limit (the alarm) from alarm_at on."""
    rows = {1_000_000 * k: {'supply_pressure': 8e6 if k / 1000 >= alarm_at else 7e6,
                            'inlet_flow': 1e-4}
            for k in range(round(end_s * 1000) + 1)}
    series = TickSeries.from_rows(rows)
    return series, np.full(len(series), 8e6)


@pytest.mark.parametrize('expectation', [
    {'no_alarm': {'from': 0.8, 'to': 0.3}},
    {'no_alarm': {'from': 5, 'to': 10}},
    {'never_above': {'signal': 'supply_pressure', 'value': '9 MPa', 'from': 5, 'to': 10}},
    {'alarm': {'after': 5, 'within': 1}},
    {'steady': {'signal': 'supply_pressure', 'flow': 1e-4, 'max': '9 MPa', 'window': 0.2}},
])
def test_a_window_without_samples_fails_with_its_reason_in_every_kind(expectation):
    """Judged on a recording (not checked against a duration first, as a bag may end early)."""
    series, limits = series_of_a_run()
    if 'steady' in expectation:  # every supply_pressure sample of the hold lost
        series.columns['supply_pressure'][:] = np.nan
    check, = evaluate(parse_expectations([expectation]), series, limits, steps=[])
    assert not check.passed
    assert 'no samples' in check.detail and 'the run has' in check.detail


def test_no_alarm_still_sees_the_alarm_in_a_window_with_samples():
    series, limits = series_of_a_run()
    passed = [check.passed for check in evaluate(parse_expectations(
        [{'no_alarm': {'to': 0.6}}, {'no_alarm': {'from': 0.3, 'to': 0.8}}]), series, limits, [])]
    assert passed == [True, False]
