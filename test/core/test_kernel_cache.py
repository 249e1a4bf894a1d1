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
The numba kernel cache: reused while the sources stand, never stale after an edit.

integrator.splits_needed inlines model.fastest_chamber_rate from another file,
which numba's own freshness check does not look at. On a copy of the package,
each run in a fresh process: the first compiles and caches, the second loads
the cache, and after an edit of model.py the third compiles the edited function.
A cache index that no longer unpickles (a class it names has moved) is compiled
over, not an error.
"""

import os
from pathlib import Path
import pickle
import shutil
import subprocess
import sys

import pytest


numba = pytest.importorskip('numba')

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = """
import numpy as np
import valve_sim
from valve_sim.core.coefficients import coefficients
from valve_sim.core.integrator import splits_needed
from valve_sim.core.parameters import load_parameters

print('package', valve_sim.__file__)
params = load_parameters().params
print('splits', splits_needed(np.zeros(8), coefficients(params), 1e-5))
"""
ORIGINAL = '    return max(\n        c_s * (throttle_1 + bearing + leak + seat)'
EDITED = '    return 1e-9 * max(\n        c_s * (throttle_1 + bearing + leak + seat)'


def run(copy):
    """Run SCRIPT on the copy in a fresh process; return (splits, numba's cache log)."""
    env = {
        key: value
        for key, value in os.environ.items()
        if key not in ('NUMBA_CACHE_DIR', 'NUMBA_DISABLE_JIT', 'PYTHONPATH')
    }
    env.update(PYTHONPATH=str(copy), PYTHONDONTWRITEBYTECODE='1', NUMBA_DEBUG_CACHE='1')
    done = subprocess.run(
        [sys.executable, '-c', SCRIPT],
        cwd=copy,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert f'package {copy / "valve_sim" / "__init__.py"}' in lines
    kernel_log = [line for line in lines if 'integrator.splits_needed' in line]
    return int(lines[-1].split()[-1]), ' '.join(kernel_log)


def copy_package(folder):
    """Copy the package and its config into folder, without any compiled kernel."""
    ignore = shutil.ignore_patterns('__pycache__')
    shutil.copytree(ROOT / 'valve_sim', folder / 'valve_sim', ignore=ignore)
    shutil.copytree(ROOT / 'config', folder / 'config', ignore=ignore)


def test_an_edit_of_an_inlined_function_in_another_file_is_compiled(tmp_path):
    copy_package(tmp_path)
    first, log = run(tmp_path)
    assert first > 1  # the empty, closed valve is stiff: its steps are split
    assert 'data saved' in log
    again, log = run(tmp_path)
    assert again == first
    assert 'data loaded' in log and 'data saved' not in log  # the cache is used
    model = tmp_path / 'valve_sim' / 'core' / 'model.py'
    source = model.read_text()
    assert source.count(ORIGINAL) == 1
    model.write_text(source.replace(ORIGINAL, EDITED))
    edited, log = run(tmp_path)
    assert edited == 1  # the edited (much slower) rate needs no split
    assert 'data saved' in log


def test_an_index_that_no_longer_unpickles_is_compiled_over(tmp_path):
    """An index naming a class that is not there (it moved) reads as empty: compiled anew."""
    copy_package(tmp_path)
    first, log = run(tmp_path)
    assert 'data saved' in log
    (index,) = (tmp_path / 'valve_sim' / 'core' / '__pycache__').glob(
        'integrator.splits_needed-*.nbi'
    )
    with open(index, 'wb') as f:  # numba's layout: its version, then the pickled index
        pickle.dump(numba.__version__, f, protocol=-1)
        f.write(b'cvalve_sim.core.model\nMovedAway\n.')  # unpickles to a missing attribute
    with pytest.raises(AttributeError):
        pickle.loads(index.read_bytes()[len(pickle.dumps(numba.__version__, protocol=-1)):])
    again, log = run(tmp_path)
    assert again == first
    assert 'data saved' in log  # compiled over, the index written anew
    third, log = run(tmp_path)
    assert third == first
    assert 'data loaded' in log and 'data saved' not in log
