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
Every source file carries a copyright notice and the Apache-2.0 licence of package.xml.

ament_copyright is not on PyPI, so this follows its rules where it is missing: the
first comment block of each Python file (after a shebang) names a year and a
copyright holder and holds the Apache 2.0 notice. On a ROS install with
ament_copyright, ament_copyright itself runs.
"""
from pathlib import Path
import re

import pytest

ROOT = Path(__file__).resolve().parents[2]
COPYRIGHT = re.compile(r'^# Copyright (\d{4})(-\d{4})? \S.*$', re.MULTILINE)
APACHE_NOTICE = [
    'Licensed under the Apache License, Version 2.0 (the "License");',
    'http://www.apache.org/licenses/LICENSE-2.0',
    'limitations under the License.',
]


def python_files(paths):
    for path in map(Path, paths):
        yield from ([path] if path.is_file() else sorted(path.rglob('*.py')))


def first_comment_block(path):
    lines = path.read_text().splitlines()
    if lines and lines[0].startswith('#!'):
        lines = lines[1:]
    block = []
    for line in lines:
        if not line.startswith('#'):
            break
        block.append(line)
    return '\n'.join(block)


@pytest.mark.copyright
@pytest.mark.linter
def test_copyright(lint_paths):
    try:
        from ament_copyright.main import main
    except ImportError:
        main = None
    if main is not None:
        assert main(argv=lint_paths) == 0
        return
    files = list(python_files(lint_paths))
    assert len(files) > 10, f'expected the package sources, found {files}'
    missing = [str(path.relative_to(ROOT)) for path in files if not has_notice(path)]
    assert missing == [], f'files without the copyright and Apache-2.0 notice: {missing}'


def has_notice(path):
    header = first_comment_block(path)
    return bool(COPYRIGHT.search(header)) and all(text in header for text in APACHE_NOTICE)


def test_a_file_without_the_notice_is_found(tmp_path):
    bare = tmp_path / 'bare.py'
    bare.write_text('#!/usr/bin/env python3\n# Copyright 2026 someone\n\nprint(1)\n')
    assert not has_notice(bare)
    assert has_notice(Path(__file__))


def test_the_licence_file_matches_package_xml():
    assert '<license>Apache-2.0</license>' in (ROOT / 'package.xml').read_text()
    assert 'Apache License' in (ROOT / 'LICENSE').read_text()
    assert 'Version 2.0' in (ROOT / 'LICENSE').read_text()


def test_vendored_sources_keep_their_licences_where_ament_copyright_does_not_look(lint_paths):
    """
    Third-party C/C++ (the FMU binary's, pythonfmu's MIT) sits in a folder starting with '_'.

    ament_copyright skips those folders, as it skips the vendored simulation_interfaces
    outside the lint paths; the folder keeps pythonfmu's LICENSE, each FMI header its BSD
    notice, as their licences ask.
    """
    vendored = [
        path for root in map(Path, lint_paths) if root.is_dir() for path in root.rglob('*')
        if path.suffix in ('.c', '.cc', '.cpp', '.cxx', '.h', '.hh', '.hpp', '.hxx')
        and any(part.startswith(('_', '.')) for part in path.relative_to(root).parts[:-1])
    ]
    assert len(vendored) >= 3, 'the FMU binary sources: valve_sim/fmu/_pythonfmu_export'
    for path in vendored:
        folder = next(parent for parent in path.parents if parent.name.startswith('_'))
        assert 'Permission is hereby granted' in (folder / 'LICENSE').read_text(), path
        if path.parent.name == 'fmi':
            assert 'BSD 2-Clause' in path.read_text(encoding='latin-1'), path
