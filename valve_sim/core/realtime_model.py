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
The valve model advanced in step with a clock: the core of valve_node, without ROS.

Model time is kept in integer nanoseconds of the clock it follows. Each call of
advance_to() integrates the whole number of fixed steps that fit between the
model time and the clock, and carries the rest (less than one step) into the next
call, so the model time never drifts from the clock. A lag beyond the catch-up
limit is skipped: the model time jumps and the state is held over that stretch.
"""

from dataclasses import dataclass

import numpy as np
from valve_sim.core.faults import HEALTHY
from valve_sim.core.integrator import advance
from valve_sim.core.model import coefficients
from valve_sim.core.simulation import apply_faults
from valve_sim.core.steady_state import steady_state


NS_PER_S = 1_000_000_000
TRIAL_STEPS = 2000  # steps a parameter change is trial-integrated for before it is accepted


def step_ns(step_size):
    """
    Return a step size [s] as whole nanoseconds (at least 1).

    Whole nanoseconds are the grid the model time moves on.
    """
    return max(1, round(step_size * NS_PER_S))


@dataclass(frozen=True)
class Progress:
    """What one advance_to() did: steps integrated and clock time skipped [ns]."""

    steps: int
    skipped_ns: int


class RealTimeModel:
    """
    The valve state, its parameters and its model time [ns].

    params: validated parameter dict; step_size [s]; inlet_flow [m^3/s]: the
    flow whose exact steady state is the initial state; faults: the FaultSet in
    effect. The model time is None until start() anchors it to the clock.
    """

    def __init__(self, params, step_size, inlet_flow, faults=HEALTHY):
        self.state = steady_state(params, inlet_flow, faults)
        self.time_ns = None
        self._use(params, step_size, faults)
        self._previous = None  # (params, step_size, faults) before the last retune

    def _use(self, params, step_size, faults):
        self.params = params
        self.step_size = step_size
        self.faults = faults
        self._coefficients = coefficients(params, faults)
        self._step_ns = step_ns(step_size)

    def start(self, now_ns):
        """Anchor the model time to the clock time now_ns [ns] without integrating."""
        self.time_ns = now_ns

    def advance_to(self, now_ns, inlet_flow, max_lag_ns):
        """
        Integrate with inlet_flow [m^3/s] held, up to the clock time now_ns [ns].

        Clock time beyond max_lag_ns [ns] behind now_ns is skipped first. Returns
        Progress. On divergence raises IntegrationError and leaves state and
        model time unchanged.
        """
        skipped_ns = max(now_ns - self.time_ns - max_lag_ns, 0)
        steps = (now_ns - self.time_ns - skipped_ns) // self._step_ns
        advance(
            self.state,
            np.full(steps, float(inlet_flow)),
            self._coefficients,
            self._step_ns / NS_PER_S,
            time=self.time_ns / NS_PER_S,
        )
        self.time_ns += skipped_ns + steps * self._step_ns
        return Progress(steps, skipped_ns)

    def hold_until(self, now_ns):
        """Move the model time to the last step boundary before now_ns [ns], holding the state."""
        self.time_ns += (now_ns - self.time_ns) // self._step_ns * self._step_ns

    def trial(self, params, step_size, inlet_flow, faults=None):
        """
        Integrate TRIAL_STEPS steps from a copy of the state with new parameters (and faults).

        Raises IntegrationError if they diverge; the model itself is not touched.
        """
        state = self.state.copy()
        faults = self.faults if faults is None else apply_faults(state, self.faults, faults)
        advance(
            state,
            np.full(TRIAL_STEPS, float(inlet_flow)),
            coefficients(params, faults),
            step_ns(step_size) / NS_PER_S,
        )

    def retune(self, params, step_size, faults=None):
        """
        Use new parameters (validated dict) and step size [s] from the next step on.

        faults: {name: value} of fault parameters changed too (None: none); a main
        valve that becomes stuck stops where it is.
        """
        self._previous = (self.params, self.step_size, self.faults)
        faults = self.faults if faults is None else apply_faults(self.state, self.faults, faults)
        self._use(params, step_size, faults)

    def roll_back(self):
        """
        Return to the parameters and step size in use before the last retune().

        Returns False if there is nothing to return to (never retuned, or rolled back already).
        """
        if self._previous is None:
            return False
        self._use(*self._previous)
        self._previous = None
        return True

    def reset(self, inlet_flow):
        """
        Re-initialise at the exact steady state for inlet_flow [m^3/s] with the faults in effect.

        Raises SteadyStateError.
        """
        self.state = steady_state(self.params, inlet_flow, self.faults)
