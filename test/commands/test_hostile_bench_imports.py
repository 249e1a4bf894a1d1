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


"""bench/attack.sh runs every class: each class's suite modules import (issue 43, section 5)."""

from pathlib import Path
import subprocess
import sys

import pytest

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.timeout(120)
def test_every_attack_class_can_import_the_suite_modules_it_uses():
    """A test moved to another folder must not silently drop a class from the bench."""
    result = subprocess.run([sys.executable, str(REPO / 'bench' / 'attack.py'), '--check-imports'],
                            capture_output=True, text=True, timeout=110, cwd=REPO)
    assert result.returncode == 0, result.stderr
