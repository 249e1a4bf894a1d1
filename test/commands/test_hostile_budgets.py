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
Files read within their budget, errors in one line (issue 43, section 4).

- parse_json (every JSON input) in memory proportional to the file, escapes or not;
- a NaN parameter reported as nan; a negative ±X tolerance refused;
- scenario run's --wait-topic checked before any node starts;
- an optional feature without its extra: one line naming the extra;
- one divergence after another: logged at most once a second in valve_node.
"""

import sys
import tracemalloc

import pytest
from valve_sim.commands.cli import main
from valve_sim.core.errors import InputFileError, IntegrationError, ParameterError
from valve_sim.core.input_documents import parse_json
from valve_sim.core.input_files import STUDY_ROW
from valve_sim.core.parameters import check_value
from valve_sim.core.realtime_model import Outcome, Status


pytestmark = pytest.mark.timeout(120)

CHARACTERS = 2_000_000
OPTIMISE = ['optimise', '--design', 'd_c=±5%', '--minimise', 'P_1_percent', '--out', 'o']


@pytest.mark.parametrize('text', [
    '{"a": "' + 'x' * CHARACTERS + '"}',  # one long line (a results row)
    '{"a": "' + '\\n\\"' * (CHARACTERS // 4) + '"}',  # escapes all along it
    '{"a": "' + 'x' * CHARACTERS,  # a string never closed
])
def test_parse_json_memory_is_proportional_to_the_text(text):
    """Peak Python memory within a few bytes a character (a regex took ~140)."""
    tracemalloc.start()
    try:
        parse_json(text, STUDY_ROW, 'row')
    except InputFileError:
        pass
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 4 * len(text), f'{peak / len(text):.1f} bytes a character'


def test_nesting_and_count_are_still_refused():
    with pytest.raises(InputFileError, match='nested more than'):
        parse_json('[' * 40 + ']' * 40, STUDY_ROW, 'row')
    assert parse_json('{"a": "[[[[\\"{{{{"}', STUDY_ROW, 'row') == {'a': '[[[["{{{{'}


def test_a_nan_parameter_is_reported_as_nan(capsys):
    with pytest.raises(ParameterError, match='must be finite, got nan'):
        check_value('k_p', float('nan'))
    with pytest.raises(ParameterError, match='got inf'):
        check_value('k_p', 10 ** 400)
    assert main(['simulate', '--set', 'k_p=nan']) == 1
    assert 'got nan' in capsys.readouterr().err


def test_a_negative_tolerance_is_refused(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main([*OPTIMISE, '--tolerance', 'd_c=±-1%']) == 1
    assert 'must be >= 0' in capsys.readouterr().err
    assert not (tmp_path / 'o' / 'pareto.json').exists()


@pytest.mark.parametrize('topic', ['bad topic!!', '', '/a//b'])
def test_a_wait_topic_is_checked_before_the_nodes_start(capsys, monkeypatch, topic):
    def no_run(*args, **options):
        raise AssertionError('the nodes were started')

    monkeypatch.setattr('valve_sim.ros.scenario_runner.run_and_report', no_run)
    with pytest.raises(SystemExit) as exit_code:
        main(['scenario', 'run', 'scenarios/paper_step.yaml', '--wait-topic', topic])
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert exit_code.value.code == 2 and 'is not a ROS topic name' in error


@pytest.mark.parametrize('arguments, module, extra', [
    (['fmu', '--out', 'x.fmu'], 'pythonfmu', 'fmu'),
    ([*OPTIMISE, '--tolerance', 'd_c=±5um'], 'pymoo', 'studies'),
    (['sensitivity', '--out', 'o'], 'SALib', 'studies'),
])
def test_a_feature_without_its_extra_says_which_in_one_line(
    capsys, monkeypatch, tmp_path, arguments, module, extra
):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setitem(sys.modules, module, None)  # import fails: as if not installed
    assert main(arguments) == 1
    error = capsys.readouterr().err.strip()
    assert f"the '{extra}' extra" in error and module in error and '\n' not in error


def test_one_divergence_after_another_logs_at_most_once_a_second():
    """A tank pressure flipping every tick: each tick a failure, logged rate-limited."""
    from valve_sim.ros.node_status import Counters
    from valve_sim.ros.tick_logs import TickLogs
    from valve_sim.ros.valve_node import CATCH_UP_LIMIT_PERIODS

    lines = []

    class Logger:

        def error(self, text):
            lines.append(text)

        info = warn = error

    logs = TickLogs(Logger(), Counters(), CATCH_UP_LIMIT_PERIODS)  # valve_node's, as it makes them
    for _ in range(2000):
        logs.failure(Outcome(Status.FAILURE, error=IntegrationError('diverged')), saturated=None)
    assert 1 <= len(lines) <= 10, len(lines)
