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
"""

try:
    from numba import njit
except ImportError:  # pragma: no cover - exercised only on machines without numba
    njit = None


def jit(function, cache=True):
    """
    numba.njit if available, else the function itself.

    error_model="numpy": a division by zero gives inf (caught by the state check)
    instead of a Python exception, which keeps branches out of the inner loop.
    cache=False for a function without a source file (generated with exec).
    """
    if njit is None:
        return function
    return njit(cache=cache, nogil=True, error_model='numpy', inline='always')(function)
