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
The paper's test as data: an inlet-flow step (or ramp) from one steady flow to another.

TankPressure is the second input's profile the same way: the tank's (back) pressure held,
stepped or ramped. Kept apart from the simulation so that the command line and the
paper's reference data can name flow steps without loading the integrator (numba) or scipy.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


LITRE_PER_MINUTE = 1e-3 / 60.0  # [m^3/s]


@dataclass(frozen=True)
class FlowStep:
    """Inlet-flow step test. Flows in m^3/s, times in s."""

    initial_flow: float = 5.0 * LITRE_PER_MINUTE
    final_flow: float = 20.0 * LITRE_PER_MINUTE
    step_time: float = 0.25
    end_time: float = 1.25
    ramp_time: float = 0.0

    def inlet_flow(self, t: ArrayLike) -> np.ndarray:
        """q_in(t) [m^3/s] (vectorised)."""
        return stepped(t, self.initial_flow, self.final_flow, self.step_time, self.ramp_time)


@dataclass(frozen=True)
class TankPressure:
    """
    The tank's pressure p_t [Pa, gauge]: initial, changed to final at step_time [s].

    At once, or linearly over ramp_time [s]; final None: held at initial. The default
    is the tank at ambient, the paper's case.
    """

    initial: float = 0.0
    final: Optional[float] = None
    step_time: float = 0.0
    ramp_time: float = 0.0

    def at(self, t: ArrayLike) -> np.ndarray:
        """p_t(t) [Pa, gauge] (vectorised)."""
        final = self.initial if self.final is None else self.final
        return stepped(t, self.initial, final, self.step_time, self.ramp_time)


def stepped(t, initial, final, step_time, ramp_time):
    """Return initial before step_time, final from then on (or a ramp over ramp_time), at t."""
    t = np.asarray(t, dtype=float)
    if ramp_time > 0.0:
        progress = np.clip((t - step_time) / ramp_time, 0.0, 1.0)
    else:
        progress = (t >= step_time).astype(float)
    return initial + (final - initial) * progress
