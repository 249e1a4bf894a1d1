"""The errors a user can cause (bad parameters, bad files, a diverging run).

The command line prints these as one line and exits 1; anything else is a bug
and keeps its traceback.
"""

from valve_sim.core.integrator import IntegrationError
from valve_sim.core.parameters import ParameterError
from valve_sim.core.steady_state import SteadyStateError


class InputFileError(ValueError):
    """A file given by the user cannot be read or has the wrong content."""


USER_ERRORS = (ParameterError, IntegrationError, SteadyStateError, InputFileError, OSError)
