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

"""A scenario's report shows valve_node's invariant alarms that fired, and only those."""

from pathlib import Path
from types import SimpleNamespace

from valve_sim.analysis.scenarios.report import report_document, report_text


def run_with(alarms):
    scenario = SimpleNamespace(name='s', path=Path('s.yaml'), description='', duration=1.0,
                               period_ns=1_000_000)
    return SimpleNamespace(scenario=scenario, checks=[], series=None, wall_s=1.0, speed=1.0,
                           bag=Path('b.mcap'), error=None, passed=False, start_ns=0,
                           clock_steps=1, steps=[], invariant_alarms=alarms)


def test_fired_invariant_alarms_are_in_the_report_and_quiet_counts_are_not():
    fired = run_with('bounds: 0, continuity: 2, flow_balance: 0')
    assert 'WARNING: invariant alarms of valve_node: continuity: 2' in report_text(fired)
    assert report_document(fired)['invariant_alarms'] == 'continuity: 2'
    quiet = run_with('bounds: 0, continuity: 0, flow_balance: 0')
    assert 'invariant' not in report_text(quiet)
    assert report_document(quiet)['invariant_alarms'] == ''
