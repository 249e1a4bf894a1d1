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
Compile the numerical kernels with numba when it is installed.

The kernels are plain Python; numba only makes them fast enough for real time
(a 1 ms tick is 100 RK4 steps). Without numba they run unchanged, slowly.

Compiled kernels are cached on disk (numba's cache, in __pycache__ beside the
sources or wherever numba would put it). numba judges a cached kernel fresh by
its own source file only, but a kernel inlines functions and constants from other
files of valve_sim.core (the integrator inlines the model's equations): after an
edit of model.py, or a `git pull` that changes it, numba would keep running the
old equations. So every kernel's cache entry is also stamped with one digest of
all valve_sim/core sources (SOURCES_DIGEST): any change there recompiles every
kernel on its next use. Hashing the sources costs about a millisecond at import.

numba's index of a kernel's cache entries is a pickle that names classes by module
(a kernel's signature names model.Coefficients): after such a class has moved, or
any other change that leaves an index unreadable, numba would raise on loading it
and stop the first start. An index that does not unpickle counts as an empty cache
here: the kernel is compiled again and the index written anew.
"""

import hashlib
from pathlib import Path

try:
    from numba import njit
except ImportError:  # pragma: no cover - exercised only on machines without numba
    njit = None


def sources_digest(folder=Path(__file__).parent):
    """Return a SHA-256 hex digest of the contents of every .py file in folder (by name)."""
    digest = hashlib.sha256()
    for path in sorted(folder.glob('*.py')):
        digest.update(path.name.encode() + b'\0' + path.read_bytes() + b'\0')
    return digest.hexdigest()


SOURCES_DIGEST = sources_digest()


def _stamped_cache_class():
    """
    Return numba's FunctionCache with every source stamp joined to SOURCES_DIGEST.

    The cache's location is the one numba itself chooses (NUMBA_CACHE_DIR, the
    source tree's __pycache__, or the user-wide cache when that is not writable);
    only its freshness check changes, and an unreadable index reads as empty. None
    where this numba's cache does not have the expected form: then the kernels are
    compiled in each process, never stale.
    """
    try:
        from numba.core.caching import CompileResultCacheImpl, FunctionCache, IndexDataCacheFile
    except ImportError:  # pragma: no cover - a numba without this caching layout
        return None
    numba_locators = tuple(CompileResultCacheImpl._locator_classes)

    class StampedLocator:
        """numba's own locator for the function, stamped with SOURCES_DIGEST too."""

        def __init__(self, locator):
            self._locator = locator

        def __getattr__(self, name):
            return getattr(self._locator, name)

        def get_source_stamp(self):
            return (self._locator.get_source_stamp(), SOURCES_DIGEST)

        @classmethod
        def from_function(cls, py_func, py_file):
            for locator_class in numba_locators:
                locator = locator_class.from_function(py_func, py_file)
                if locator is not None:
                    return cls(locator)
            return None

    class StampedCacheImpl(CompileResultCacheImpl):
        _locator_classes = [StampedLocator]

    class ReadableIndexFile(IndexDataCacheFile):
        """numba's index and data files, with an index that does not unpickle read as empty."""

        def _load_index(self):
            try:
                return super()._load_index()
            except Exception:  # AttributeError, ImportError, UnpicklingError, EOFError, ...
                return {}

    class StampedFunctionCache(FunctionCache):
        _impl_class = StampedCacheImpl

        def __init__(self, py_func):
            super().__init__(py_func)
            self._cache_file = ReadableIndexFile(
                cache_path=self._cache_path,
                filename_base=self._impl.filename_base,
                source_stamp=self._impl.locator.get_source_stamp(),
            )

    return StampedFunctionCache


_CACHE_CLASS = _stamped_cache_class() if njit is not None else None


def jit(function, cache=True):
    """
    numba.njit if available, else the function itself.

    error_model="numpy": a division by zero gives inf (caught by the state check)
    instead of a Python exception, which keeps branches out of the inner loop.
    inline="always": a kernel that calls another compiles its body in, so the
    compiler optimises across them (and vectorises loops over their calls).
    cache=False for a function without a source file (generated with exec).
    """
    if njit is None:
        return function
    dispatcher = njit(nogil=True, error_model='numpy', inline='always')(function)
    if cache and _CACHE_CLASS is not None:
        dispatcher._cache = _CACHE_CLASS(function)  # what njit(cache=True) sets, restamped
    return dispatcher
