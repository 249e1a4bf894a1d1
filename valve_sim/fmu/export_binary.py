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
The FMU's binary: pythonfmu 0.7's export library, patched (_pythonfmu_export/), built here.

binary() returns the shared library the FMU carries as binaries/linux64/ReliefValve.so,
compiled once with the C++ compiler ($CXX, else g++) against this Python's headers, with
Python's stable ABI (Py_LIMITED_API 3.8: any CPython 3.8 or later loads it), and cached
by the hash of its sources and flags beside this module (else in the user's cache folder).
What the patch changes and why: _pythonfmu_export/README.md.
"""

import hashlib
import os
from pathlib import Path
import shutil
import subprocess
import sys
import sysconfig
import tempfile

from valve_sim.core.errors import BuildError


SOURCES = Path(__file__).resolve().parent / '_pythonfmu_export'
UNITS = ('pythonfmu/fmi2.cpp', 'pythonfmu/PySlaveInstance.cpp')
FLAGS = ('-std=c++17', '-O2', '-fPIC', '-DPy_LIMITED_API=0x03080000')
NAME = 'libpythonfmu-export.so'


def binary(say=print):
    """Return the path of the built library, building it first if needed (say() tells)."""
    if sys.platform != 'linux' or sys.maxsize < 2**32:  # its one binary: binaries/linux64
        raise BuildError('valve-sim fmu builds the FMU on 64-bit Linux only, not on '
                         f"{sys.platform} ({'64' if sys.maxsize >= 2**32 else '32'}-bit)")
    digest = hashlib.sha256(repr(FLAGS).encode())
    for path in sorted(SOURCES.rglob('*')):
        if path.suffix in ('.cpp', '.hpp', '.h'):
            digest.update(path.relative_to(SOURCES).as_posix().encode() + path.read_bytes())
    built = cache_folder() / f'pythonfmu-export-{digest.hexdigest()[:16]}' / NAME
    if not built.is_file():
        compile_library(built, say)
    return built


def notices():
    """Return {path in the FMU: text}: the licences the binary's sources ask it to carry."""
    header = (SOURCES / 'fmi' / 'fmi2TypesPlatform.h').read_text(encoding='latin-1')
    start = header.index('Copyright')
    return {
        'documentation/licenses/pythonfmu-export.txt': (SOURCES / 'LICENSE').read_text(),
        'documentation/licenses/fmi2-headers.txt': header[start:header.index('*/', start)],
    }


def cache_folder():
    """__pycache__ beside this module if writable (as numba's kernels), else the user's cache."""
    folder = Path(__file__).resolve().parent / '__pycache__'
    if os.access(folder if folder.exists() else folder.parent, os.W_OK):
        return folder
    return Path(os.environ.get('XDG_CACHE_HOME') or Path.home() / '.cache') / 'valve_sim'


def missing_tools():
    """Return why the library cannot be compiled here (no compiler, no Python.h), else None."""
    compiler, include = _tools()
    if compiler is None or not (include / 'Python.h').is_file():
        return ('building the FMU needs a C++ compiler (g++, or $CXX) and the headers of '
                f'Python {sys.version.split()[0]} ({include}/Python.h; Debian: python3-dev), '
                f"found {'no compiler' if compiler is None else 'no Python.h'}")
    return None


def _tools():
    """Return (the C++ compiler's path or None, this Python's include folder)."""
    wanted = os.environ.get('CXX')
    compiler = shutil.which(wanted) if wanted else shutil.which('g++') or shutil.which('c++')
    return compiler, Path(sysconfig.get_paths()['include'])


def compile_library(target, say):
    """Compile the two sources into target (written whole: a temporary file renamed)."""
    missing = missing_tools()
    if missing:
        raise BuildError(missing)
    compiler, include = _tools()
    say(f'compiling the FMU binary into {target.parent} (once; 10 s of CPU)')
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=target.parent, suffix='.so', delete=False) as partial:
        pass
    command = [compiler, *FLAGS, '-shared', f'-I{SOURCES}', f'-I{include}',
               *(str(SOURCES / unit) for unit in UNITS), '-o', partial.name]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        os.unlink(partial.name)
        log = target.parent / 'build.log'
        log.write_text(' '.join(command) + '\n' + result.stderr)
        raise BuildError(f'building the FMU binary failed ({Path(compiler).name} exit '
                         f'{result.returncode}): its command and messages are in {log}')
    os.replace(partial.name, target)
