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


REPO = Path(__file__).resolve().parents[2]
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


README_MAX_LINES = 250  # issue 27: the README a newcomer reads; the rest is in docs/


def test_the_readme_stays_a_newcomers_size():
    lines = len((REPO / 'README.md').read_text().splitlines())
    assert lines <= README_MAX_LINES, f'README.md has {lines} lines: move detail to docs/'


def test_the_docs_index_lists_every_page():
    index = REPO / 'docs' / 'README.md'
    listed = set(LINK.findall(index.read_text()))
    pages = {p.name for p in (REPO / 'docs').glob('*.md')} - {index.name}
    assert sorted(pages - listed) == []


def test_the_readme_layout_names_every_wing_and_module():
    """The README's Layout section names each wing of valve_sim and each of its modules."""
    readme = (REPO / 'README.md').read_text()
    layout = readme.split('\n## Layout\n', 1)[1].split('\n## ', 1)[0]
    named = set(re.findall(r'[a-z_0-9]+', layout))
    package = REPO / 'valve_sim'
    missing = [
        str(path.relative_to(package))
        for path in sorted(package.rglob('*.py'))
        if '__pycache__' not in path.parts
        and (path.stem if path.stem != '__init__' else path.parent.name) not in named
    ]
    assert missing == []


def test_docs_define_the_measures_and_the_equations():
    measures = (REPO / 'docs' / 'measures.md').read_text()
    for name in ('P_o_percent', 'P_1_percent', 'T_1_ms', 'r_d', 'T_d_ms', 'T_s_ms', 'p_inf'):
        assert name in measures, name
    model = (REPO / 'docs' / 'model.md').read_text()
    for number in range(1, 17):  # each equation is stated or derived with its number
        assert re.search(rf'\({number}\)|Eqs?\. [^.]*\b{number}\b', model), number
