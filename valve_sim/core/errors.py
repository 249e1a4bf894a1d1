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
The errors a user can cause (bad parameters, bad files, a diverging run).

The command line prints these as one line and exits 1; anything else is a bug
and keeps its traceback. Defined here, light to import (no numba, no scipy), and
also offered by the modules that raise them (integrator, steady_state; InputFileError
lives with the file readers, input_files).
"""

from valve_sim.core.input_files import InputFileError
from valve_sim.core.parameters import ParameterError


class IntegrationError(RuntimeError):
    """
    The integration diverged or produced a non-finite state.

    steps_done: the steps of the call completed before the failing one.
    """

    steps_done = 0


class OverpressureError(IntegrationError):
    """A chamber pressure passed burst_pressure: a physical limit, not a numerical failure."""


class SteadyStateError(RuntimeError):
    """No steady state could be found."""


class IncompleteRunError(RuntimeError):
    """A run ended without all it was to produce; the message says what is missing and why."""


class StudyError(RuntimeError):
    """A study cannot run or complete (its results file, its cluster)."""


# What one valve of a study can fail with (recorded as that case's error).
MODEL_ERRORS = (ParameterError, IntegrationError, SteadyStateError)
USER_ERRORS = (*MODEL_ERRORS, InputFileError, IncompleteRunError, StudyError, OSError)
