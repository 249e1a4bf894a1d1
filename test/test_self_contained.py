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

"""A clone carries its own documentation: nothing points outside the repository."""

from pathlib import Path
import re

import pytest


REPO = Path(__file__).resolve().parent.parent
SKIPPED = {'.venv', '.git', '__pycache__', 'build', 'install', 'log', 'out', '.pytest_cache'}
TEXT = {'.py', '.md', '.yaml', '.xml', '.sh', '.cfg', '.txt', '.json'}
OUTSIDE = re.compile(r'\.\./shared|/work/|\.\./\.\./')
LINK = re.compile(r'\]\(([^)#\s]+)')


def project_files():
    """Yield the project's text files (no environment, build output or recordings)."""
    for path in sorted(REPO.rglob('*')):
        parts = set(path.relative_to(REPO).parts)
        if (
            path.is_file()
            and path.suffix in TEXT
            and not parts & SKIPPED
            and not any(part.startswith('demo_') or part.endswith('.egg-info') for part in parts)
        ):
            yield path


def test_no_file_points_outside_the_repository():
    offending = [
        f'{path.relative_to(REPO)}:{number}: {line.strip()}'
        for path in project_files()
        for number, line in enumerate(path.read_text(errors='replace').splitlines(), 1)
        if OUTSIDE.search(line) and path.name != Path(__file__).name
    ]
    assert offending == []


PAGES = ['README.md', *sorted(f'docs/{p.name}' for p in (REPO / 'docs').glob('*.md'))]


@pytest.mark.parametrize('page', PAGES)
def test_every_relative_link_of_the_docs_resolves(page):
    path = REPO / page
    broken = [
        target
        for target in LINK.findall(path.read_text())
        if '://' not in target and not (path.parent / target).exists()
    ]
    assert broken == []


def test_docs_define_the_measures_and_the_equations():
    measures = (REPO / 'docs' / 'measures.md').read_text()
    for name in ('P_o_percent', 'P_1_percent', 'T_1_ms', 'r_d', 'T_d_ms', 'T_s_ms', 'p_inf'):
        assert name in measures, name
    model = (REPO / 'docs' / 'model.md').read_text()
    for number in range(1, 17):  # each equation is stated or derived with its number
        assert re.search(rf'\({number}\)|Eqs?\. [^.]*\b{number}\b', model), number
