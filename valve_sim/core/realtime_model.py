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

Two inputs drive it, held over each call: the inlet flow and the tank pressure. Out come
the state and the relief flow (relief_flows()), what the valve passes to the tank.

The owner calls update() with the clock time, as ros2_control's resource manager calls
a simulated system's read() with the time and period, and gets an Outcome back: the
failure policy is decided here, the owner (valve_node, a test) only reports it. When the
state leaves the physical limits (valve_sim.core.limits: an overpressure, or a
divergence) the model keeps its last good state. If a parameter change took effect
within the trial window (TRIAL_STEPS steps) before, that change can have caused it and
roll_back() undoes it; any other cause leaves the parameters alone and halt() stops the
model: it holds its state, its time following the clock, until resume() (a reset, a new
inlet flow or a parameter change). After an overpressure halt, output_state() reads p_s
at burst_pressure, the limit it passed, as a transducer at full scale reads.

After each advance_to() that integrated, monitor (valve_sim.core.invariants.Monitor) judges
the state: its alarms name a violated invariant, its size and the model time.
"""

from dataclasses import dataclass
from enum import Enum
from typing import Optional

import numpy as np
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import IntegrationError, OverpressureError
from valve_sim.core.faults import HEALTHY
from valve_sim.core.integrator import advance
from valve_sim.core.invariants import Monitor
from valve_sim.core.model import relief_flows, STATE_NAMES
from valve_sim.core.parameters import STANDARD_ATMOSPHERE, validate
from valve_sim.core.simulation import apply_faults
from valve_sim.core.steady_state import steady_state
from valve_sim.core.step_check import check_integrable


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


class Status(Enum):
    """What one update() came to."""

    PROGRESS = 'progress'  # integrated up to the clock (lag beyond the limit skipped)
    HALTED = 'halted'  # halted before: the state held, the model time following the clock
    ROLLED_BACK = 'rolled back'  # failed; the change that can have caused it undone; runs on
    FAILURE = 'failure'  # failed; halted from now on (after any roll-back), the state held


@dataclass(frozen=True)
class Outcome:
    """
    What one update() did: status, steps integrated and clock time skipped [ns].

    error: the IntegrationError (or OverpressureError) of a failure, else None;
    rolled_back: the last parameter change was undone (ROLLED_BACK, or a FAILURE
    whose input the restored parameters refuse).
    """

    status: Status
    steps: int = 0
    skipped_ns: int = 0
    error: Optional[IntegrationError] = None
    rolled_back: bool = False

    @property
    def overpressure(self):
        """Return whether the failure was a state beyond burst_pressure (not a divergence)."""
        return isinstance(self.error, OverpressureError)


class RealTimeModel:
    """
    The valve state, its parameters and its model time [ns].

    params: parameter dict (validated here: ParameterError); step_size [s]; inlet_flow [m^3/s] and
    tank_pressure [Pa, gauge]: the inputs whose exact steady state is the initial
    state; faults: the FaultSet in effect. The model time is None until start()
    anchors it to the clock. tank_pressure: the tank pressure applied last.
    ambient_pressure [Pa, absolute]: the gauge pressures' zero (the vapour pressure's
    gauge value follows it: use_ambient()).
    """

    def __init__(self, params, step_size, inlet_flow, faults=HEALTHY, tank_pressure=0.0,
                 ambient_pressure=STANDARD_ATMOSPHERE):
        params = validate(params)  # ParameterError naming what is wrong or missing
        self.state = steady_state(params, inlet_flow, faults, tank_pressure, stable=False)
        check_integrable(params, step_size, faults)
        self.tank_pressure = tank_pressure
        self.ambient_pressure = ambient_pressure
        self.time_ns = None
        self._use(params, step_size, faults)
        self._previous = None  # (params, step_size, faults) before the last retune
        self._retuned_ns = None  # model time [ns] the last retune took effect (None: at start)
        self.halted = None  # why the model stopped advancing (str), or None while it runs
        self.saturated = None  # [Pa gauge] a chamber read at this limit after an overpressure
        self.saturated_chamber = None  # the state name of that chamber (the one that passed it)
        self.monitor = Monitor()  # the invariants, judged after each advance_to()
        self.relief_flows()  # its kernel loads (or compiles) here, not in the first tick

    def _use(self, params, step_size, faults):
        self.params = params
        self.step_size = step_size
        self.faults = faults
        self._coefficients = coefficients(params, faults, self.ambient_pressure)
        self._step_ns = step_ns(step_size)

    def use_ambient(self, ambient_pressure):
        """Take ambient_pressure [Pa, absolute] as the gauge zero from the next step on."""
        if ambient_pressure != self.ambient_pressure:
            self.ambient_pressure = ambient_pressure
            self._use(self.params, self.step_size, self.faults)

    def start(self, now_ns):
        """
        Anchor the model time to the clock time now_ns [ns] without integrating.

        Called again after the clock jumped back, it starts a new time base: the time of
        the last retune moves with the model time, so the roll-back window still counts
        the model time integrated since that retune.
        """
        if self.time_ns is None and self._retuned_ns is None and self._previous is not None:
            self._retuned_ns = now_ns
        elif self.time_ns is not None and self._retuned_ns is not None:
            self._retuned_ns += now_ns - self.time_ns
        self.time_ns = now_ns

    def advance_to(self, now_ns, inlet_flow, max_lag_ns, tank_pressure=0.0):
        """
        Integrate with inlet_flow [m^3/s] and tank_pressure [Pa, gauge] held, up to now_ns [ns].

        Clock time beyond max_lag_ns [ns] behind now_ns is skipped first. Returns
        Progress. When the state leaves the limits raises IntegrationError (or its
        OverpressureError) with failure_ns, the model time [ns] of the failing step,
        and leaves state and model time unchanged. A halted model only holds.
        """
        if self.halted is not None:
            self.hold_until(now_ns)
            return Progress(0, 0)
        skipped_ns = max(now_ns - self.time_ns - max_lag_ns, 0)
        steps = (now_ns - self.time_ns - skipped_ns) // self._step_ns
        try:
            advance(
                self.state,
                np.full(steps, float(inlet_flow)),
                self._coefficients,
                self._step_ns / NS_PER_S,
                time=(self.time_ns + skipped_ns) / NS_PER_S,
                tank_pressures=tank_pressure,
            )
        except IntegrationError as error:
            error.failure_ns = self.time_ns + skipped_ns + (error.steps_done + 1) * self._step_ns
            raise
        self.tank_pressure = tank_pressure
        self.time_ns += skipped_ns + steps * self._step_ns
        if skipped_ns:
            self.monitor.restart()  # the state was held over the skipped stretch
        if steps:
            self.monitor.observe(
                self.time_ns / NS_PER_S, self.state, inlet_flow, tank_pressure, self._coefficients
            )
        return Progress(steps, skipped_ns)

    def update(self, now_ns, inlet_flow, max_lag_ns, tank_pressure=0.0):
        """
        Advance to the clock time now_ns [ns] as advance_to() does; return the Outcome.

        Never raises IntegrationError: on a failure the last good state is held (the
        model time moved to now_ns), the last parameter change is rolled back if it can
        have caused it (roll_back()), and the model halts unless the roll-back let it
        run on with inlet_flow [m^3/s] (within the restored max_inlet_flow).
        """
        if self.halted is not None:
            self.hold_until(now_ns)
            return Outcome(Status.HALTED)
        try:
            progress = self.advance_to(now_ns, inlet_flow, max_lag_ns, tank_pressure)
        except IntegrationError as error:
            self.hold_until(now_ns)
            rolled_back = self.roll_back(error.failure_ns)
            if rolled_back and inlet_flow <= self.params['max_inlet_flow']:
                return Outcome(Status.ROLLED_BACK, error=error, rolled_back=True)
            self.halt(str(error))
            if isinstance(error, OverpressureError):
                self.saturated = self.params['burst_pressure']
                self.saturated_chamber = error.chamber
            return Outcome(Status.FAILURE, error=error, rolled_back=rolled_back)
        return Outcome(Status.PROGRESS, progress.steps, progress.skipped_ns)

    def halt(self, reason):
        """Stop advancing: hold the state (its time following the clock) until resume()."""
        self.halted = reason

    def resume(self):
        """Advance again from the held state; return whether the model was halted."""
        halted, self.halted, self.saturated = self.halted, None, None
        self.saturated_chamber = None
        self.monitor.restart()
        return halted is not None

    def output_state(self):
        """Return the state as read out: saturated_chamber at saturated, the limit it passed."""
        if self.saturated is None:
            return self.state
        state = self.state.copy()
        state[STATE_NAMES.index(self.saturated_chamber)] = self.saturated
        return state

    def hold_until(self, now_ns):
        """Move the model time to the last step boundary before now_ns [ns], holding the state."""
        self.time_ns += (now_ns - self.time_ns) // self._step_ns * self._step_ns

    def trial(self, params, step_size, inlet_flow, faults=None, tank_pressure=None):
        """
        Integrate TRIAL_STEPS steps from a copy of the state with new parameters (and faults).

        tank_pressure [Pa, gauge]: held during the trial (None: the one applied last).
        Raises ParameterError if the step cannot integrate them at all
        (step_check), IntegrationError if they diverge; the model itself is not touched.
        """
        state = self.state.copy()
        faults = self.faults if faults is None else apply_faults(state, self.faults, faults)
        tank_pressure = self.tank_pressure if tank_pressure is None else tank_pressure
        check_integrable(params, step_ns(step_size) / NS_PER_S, faults)
        advance(
            state,
            np.full(TRIAL_STEPS, float(inlet_flow)),
            coefficients(params, faults, self.ambient_pressure),
            step_ns(step_size) / NS_PER_S,
            tank_pressures=tank_pressure,
        )

    def retune(self, params, step_size, faults=None):
        """
        Use new parameters (validated dict) and step size [s] from the next step on.

        faults: {name: value} of fault parameters changed too (None: none); a main
        valve that becomes stuck stops where it is. A retune that changes none of
        them (the node's sensor or publish-rate changes) is no change: the change
        before it stays the one that roll_back() undoes. Returns whether it was a change.
        """
        params = validate(params)
        if params == self.params and step_size == self.step_size and not faults:
            return False
        self._previous = (self.params, self.step_size, self.faults)
        self._retuned_ns = self.time_ns
        faults = self.faults if faults is None else apply_faults(self.state, self.faults, faults)
        self._use(params, step_size, faults)
        return True

    def roll_back(self, failure_ns):
        """
        Undo the last retune() if it took effect within the trial window before failure_ns.

        failure_ns: model time [ns] of a failure (the error's failure_ns). Only a
        change that recent can have caused it (older ones passed their trial and
        ran since). Returns True if the parameters and step size were restored.
        """
        if self._previous is None:
            return False
        window_ns = TRIAL_STEPS * self._step_ns
        if self._retuned_ns is not None and failure_ns - self._retuned_ns > window_ns:
            return False
        self._use(*self._previous)
        self._previous = None
        return True

    def reset(self, inlet_flow, tank_pressure=None):
        """
        Re-initialise at the exact steady state for inlet_flow [m^3/s] with the faults in effect.

        tank_pressure [Pa, gauge]: the tank's (None: the one applied last). Raises
        SteadyStateError (the state is then unchanged): among others for an input or a
        steady state beyond the physical limits. A reset resumes a halted model.
        """
        tank_pressure = self.tank_pressure if tank_pressure is None else tank_pressure
        self.state = steady_state(
            self.params, inlet_flow, self.faults, tank_pressure, stable=False
        )
        self.tank_pressure = tank_pressure
        self.monitor.restart()
        self.resume()

    def relief_flows(self):
        """Return the flows into the tank [m^3/s]: (relief, main stage, pilot, seat leakage)."""
        main, pilot, leakage = relief_flows(self.state, self._coefficients, self.tank_pressure)
        return main + pilot + leakage, main, pilot, leakage
