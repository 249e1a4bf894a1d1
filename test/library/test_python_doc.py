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

"""docs/python.md runs: every `python` block of the page, in order, in one namespace."""

import os
from pathlib import Path
import re

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / 'docs' / 'python.md'


def code_blocks(text):
    """Return the ```python blocks of a Markdown text, in order."""
    return re.findall(r'^```python\n(.*?)^```$', text, flags=re.MULTILINE | re.DOTALL)


def test_the_python_page_runs_as_written(capsys):
    blocks = code_blocks(PAGE.read_text())
    assert len(blocks) >= 5, 'the page lost its examples'
    namespace = {}
    here = os.getcwd()
    os.chdir(ROOT)  # the page's paths are the repository's (bags/reference_step.mcap)
    try:
        for number, block in enumerate(blocks, 1):
            exec(compile(block, f'docs/python.md block {number}', 'exec'), namespace)
    finally:
        os.chdir(here)
    printed = capsys.readouterr().out
    assert '0 the run reached its end' in printed and '0 fitted' in printed
    result, measures = namespace['result'], namespace['measures']
    assert all(type(v) is float for v in [*result.values, result.cost])  # no np.float64
    assert all(type(v) is float for v in measures.values.values() if v is not None)


def test_the_readme_links_the_page():
    assert '(docs/python.md)' in (ROOT / 'README.md').read_text()
