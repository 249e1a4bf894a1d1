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
Every error valve_sim raises on purpose, under one root: ValveSimError.

A ValveSimError is something a user can cause or fix (a bad parameter, a bad file, a
run that diverges); the command line prints it as one line and exits 1, and so do
the OS errors of USER_OS_ERRORS (a path the user gave that is missing, not allowed,
a folder). Anything else is a bug and keeps its traceback. Each error is defined
here, once, and imported from here; each keeps the builtin base callers catch it by
(ValueError, RuntimeError, OSError). Light to import: no numba, no scipy.

    ValveSimError
      ParameterError (ValueError)       a parameter value, name or file is invalid
        CalibrationError                 a calibration cannot be set up
      SectionError (ValueError)         a parameter file's node sections are malformed
      InputFileError (ValueError)       a file the user gave cannot be read or is wrong
        ProfileError                     a malformed input profile (input_profile)
      OutputFileError (OSError)         a file or folder the user named cannot be written
        OutputFolderError (IsADirectoryError) a file to write is a folder
      MissingExtraError (ImportError)   an optional feature's extra is not installed
      IntegrationError (RuntimeError)   a run diverged
        OverpressureError                a chamber pressure passed burst_pressure
      SteadyStateError (RuntimeError)   no steady state
      IncompleteRunError (RuntimeError) a run ended without all it was to produce
      StudyError (RuntimeError)         a study cannot run or complete
      UndefinedResultError (ValueError) the data give the result no value (Sobol indices)
      UnavailableError (RuntimeError)   what a run needs is held by another (a ROS domain)
      WaitTimeoutError (TimeoutError)   what a run waited for did not come within its limit
      NodeExitError (ChildProcessError) a node a run started ended, or did not end cleanly
      BuildError (RuntimeError)         what valve_sim compiles could not be built (the FMU's)
"""


class ValveSimError(Exception):
    """The root of valve_sim's errors: one a user can cause, said in one line."""


class ParameterError(ValveSimError, ValueError):
    """
    A parameter value, name or file is invalid.

    The message names the parameter and the limit.
    """


class CalibrationError(ParameterError):
    """The calibration cannot be set up: bad target, bounds or parameter choice."""


class SectionError(ValveSimError, ValueError):
    """A parameter file's structure or a section name is not one rcl accepts."""


class InputFileError(ValveSimError, ValueError):
    """A file given by the user cannot be read or has the wrong content."""


class ProfileError(InputFileError):
    """A malformed input profile: the key (a dotted path) and the problem."""

    def __init__(self, key, problem):
        super().__init__(f'{key}: {problem}')


class OutputFileError(ValveSimError, OSError):
    """
    A file or folder the user named cannot be written (OSError's errno, strerror, filename).

    Raised where the file is opened, so that the path is the one the user gave.
    """


class MissingExtraError(ValveSimError, ImportError):
    """An optional feature's extra is not installed (core.extras names it)."""


class IntegrationError(ValveSimError, RuntimeError):
    """
    The integration diverged or produced a non-finite state.

    steps_done: the steps of the call completed before the failing one.
    """

    steps_done = 0


class OverpressureError(IntegrationError):
    """
    A chamber pressure passed burst_pressure: a physical limit, not a numerical failure.

    chamber: the state name of the chamber that passed it (the highest).
    """

    chamber = 'supply_pressure'


class SteadyStateError(ValveSimError, RuntimeError):
    """No steady state could be found."""


class IncompleteRunError(ValveSimError, RuntimeError):
    """A run ended without all it was to produce; the message says what is missing and why."""


class StudyError(ValveSimError, RuntimeError):
    """A study cannot run or complete (its results file, its cluster)."""


class UndefinedResultError(ValveSimError, ValueError):
    """The data give a result no value (sensitivity indices of runs without one)."""


class UnavailableError(ValveSimError, RuntimeError):
    """What a run needs is held by another run on this machine (every ROS domain)."""


class WrongTypeError(ValveSimError, TypeError):
    """A call was given a value of the wrong kind (a number where a name belongs, say)."""


class WaitTimeoutError(ValveSimError, TimeoutError):
    """What a run waited for (a node, a topic, an acknowledgement) did not come in time."""


class NodeExitError(ValveSimError, ChildProcessError):
    """A node a run started ended while it was needed, or did not end cleanly; see its log."""


class BuildError(ValveSimError, RuntimeError):
    """What valve_sim compiles could not be built: the FMU's binary (no compiler, no headers)."""


class OutputFolderError(OutputFileError, IsADirectoryError):
    """A file the user named for output is a folder: nothing is written there."""


# What one valve of a study or a calibration can fail with (recorded as that case's error).
MODEL_ERRORS = (ParameterError, IntegrationError, SteadyStateError)
# The OS errors of a path a user gave (missing, not allowed, a folder, not a folder, taken):
# their user's error, not a bug, wherever they were not already turned into a ValveSimError.
USER_OS_ERRORS = (
    FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError, FileExistsError
)
# What the command line and the nodes print as one line (exit code 1).
USER_ERRORS = (ValveSimError, *USER_OS_ERRORS)


def output_error(error, path):
    """Return an OSError met writing path as an OutputFileError naming path (the user's)."""
    return OutputFileError(error.errno, error.strerror, str(path))
