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

"""The example of docs/client.md ("Writing a client"), run as it stands against valve_node."""

from pathlib import Path
import re
import subprocess
import sys

import pytest
from valve_harness import running_valve, TIMEOUT
from valve_sim.core.parameters import STANDARD_ATMOSPHERE


pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures('valve_node_kernels')]

CLIENT_PAGE = Path(__file__).resolve().parents[2] / 'docs' / 'client.md'
NAMESPACE = '/client_example'


def client_example():
    """Return the one Python block of docs/client.md."""
    (block,) = re.findall(r'```python\n(.*?)```', CLIENT_PAGE.read_text(), flags=re.DOTALL)
    return block


def test_the_documented_client_measures_the_step_by_the_stamps(context, tmp_path):
    script = tmp_path / 'client.py'
    script.write_text(client_example())
    with running_valve(context, tmp_path / 'valve_node.log', namespace=NAMESPACE) as (_, probe):
        done = subprocess.run(
            [sys.executable, str(script), '--ros-args', '-r', f'__ns:={NAMESPACE}'],
            capture_output=True, text=True, timeout=TIMEOUT,
        )
        assert done.returncode == 0, done.stderr
        match = re.fullmatch(
            r'step ([0-9.]+) s after the first sample: p_s peaks ([0-9.]+) kPa higher, '
            r'([0-9.]+) ms after it\n',
            done.stdout,
        )
        assert match, done.stdout
        # what the probe received of the same step, by stamp: the same peak
        with probe.condition:
            applied = list(probe.applied)
            supply = list(probe.pressures['supply_pressure'])
        first_new = min(t for t, q in applied if q == 20.0 / 60000.0)
        t_step = first_new - 1_000_000
        before = next(p for t, p in reversed(supply) if t <= t_step)
        peak = max(p for t, p in supply if t_step < t <= t_step + 50_000_000)
        assert float(match[2]) == pytest.approx((peak - before) / 1e3, abs=0.05)
        assert 0.0 < float(match[3]) < 50.0
        assert before > STANDARD_ATMOSPHERE
