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
Linear modes of the valve about a steady state: how fast and how damped it rings.

The Jacobian of the model's right-hand side is taken by central differences
(steps scaled per state) at the exact steady state; its eigenvalues lambda give
the modes: frequency |Im lambda| / 2 pi, decay rate -Re lambda and damping ratio
-Re lambda / |lambda|. Each mode is named by the states that take part in it
(participation factors |w_i v_i| of its left and right eigenvectors).
mode_sensitivity() gives how each mode moves per +1 % of each parameter.
Used to check stability margins and to explain them (docs/model.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math

import numpy as np
from valve_sim.core.coefficients import coefficients
from valve_sim.core.parameters import PARAMETERS
from valve_sim.core.stability import jacobian_of
from valve_sim.core.steady_state import steady_state, with_preset_pressure


def jacobian(params, state, inlet_flow, relative_step=1e-6, tank_pressure=0.0):
    """d(state_dot)/d(state) [8 x 8] at state for inlet flow [m^3/s] and tank pressure [Pa]."""
    return jacobian_of(coefficients(params), state, inlet_flow, tank_pressure, relative_step)


STATE_SYMBOLS = ('p_s', 'p_m', 'p_p', 'p_c', 'x', 'x_dot', 'y', 'y_dot')
PARTICIPATION = 0.2  # a state takes part in a mode from this share of its participation on
# Parameters no mode depends on by construction: physical limits, not physics.
LIMITS = ('max_inlet_flow', 'burst_pressure', 'supply_pressure_limit')


@dataclass(frozen=True)
class Mode:
    """
    One linear mode: eigenvalue, frequency [Hz], decay rate [1/s], damping ratio, states.

    states: the symbols of the states that take part (participation >= PARTICIPATION),
    most first; name: what it is, from them (mode_name).
    """

    eigenvalue: complex
    states: tuple[str, ...]

    @property
    def frequency_hz(self) -> float:
        return abs(self.eigenvalue.imag) / (2.0 * math.pi)

    @property
    def decay_rate(self) -> float:
        return -self.eigenvalue.real

    @property
    def damping_ratio(self) -> float:
        return -self.eigenvalue.real / abs(self.eigenvalue)

    @property
    def name(self) -> str:
        return mode_name(self.states)


def mode_name(states):
    """Name a mode by its states: main stage (p_s, x), pilot poppet (y), main valve on V_p."""
    if 'y' in states or 'y_dot' in states:
        return 'pilot poppet'
    if 'p_s' in states:
        return 'main stage'
    if 'x_dot' in states:
        return 'main valve on V_p'
    return 'chamber ' + ', '.join(states)


def modes(
    params: Mapping[str, float], inlet_flow: float, tank_pressure: float = 0.0
) -> list[Mode]:
    """
    Return every linear mode [Mode] at the steady state of inlet_flow [m^3/s].

    tank_pressure: the back pressure [Pa, gauge]. One Mode per real eigenvalue and per
    complex pair, slowest (smallest |lambda|) first.
    """
    import scipy.linalg  # here, not at the top: valve_node's start needs only jacobian

    state = steady_state(params, inlet_flow, tank_pressure=tank_pressure, stable=False)
    eigenvalues, left, right = scipy.linalg.eig(
        jacobian(params, state, inlet_flow, tank_pressure=tank_pressure), left=True, right=True
    )
    found = []
    for k in np.argsort(np.abs(eigenvalues)):
        value = complex(eigenvalues[k])
        if value.imag < 0.0 and abs(value.imag) > 1e-6 * abs(value):
            continue  # the other of its pair
        share = np.abs(left[:, k].conj() * right[:, k])
        share /= share.sum()
        order = np.argsort(-share)
        states = tuple(STATE_SYMBOLS[i] for i in order if share[i] >= PARTICIPATION)
        found.append(Mode(value, states))
    return found


def _matched(reference, candidates):
    """Return the candidate Modes nearest (relative eigenvalue distance) to each reference Mode."""
    return [
        min(candidates, key=lambda c: abs(c.eigenvalue - mode.eigenvalue) / abs(mode.eigenvalue))
        for mode in reference
    ]


def sensitivity_parameters(params, preset_held=True):
    """
    Names of the parameters mode_sensitivity varies: all but the limits and zero values.

    With the preset held the pilot spring preload is not varied: it follows the preset.
    """
    skip = set(LIMITS) | ({'pilot_spring_preload'} if preset_held else set())
    return [spec.name for spec in PARAMETERS if spec.name not in skip and params[spec.name]]


def mode_sensitivity(
    params, inlet_flow, preset_pressure=None, names=None, percent=1.0, tank_pressure=0.0
):
    """
    Return (modes, {name: [(d frequency [Hz], d decay rate [1/s]) per mode]}) per +1 %.

    Each parameter in turn is scaled by 1 +- percent/100 and the modes at the steady
    state of inlet_flow [m^3/s] are found again; a mode's change per +1 % is the
    central difference (f(+) - f(-)) / (2 percent) of the mode nearest to it.
    preset_pressure [Pa]: held (the pilot preload re-solved, as for the study's
    cases) when given; otherwise the preload stays. names: parameters to vary
    (default sensitivity_parameters()); tank_pressure: the back pressure [Pa, gauge].
    """
    base = modes(params, inlet_flow, tank_pressure)
    names = names or sensitivity_parameters(params, preset_pressure is not None)
    table = {}
    for name in names:
        moved = []
        for sign in (1.0, -1.0):
            case = {**params, name: params[name] * (1.0 + sign * percent / 100.0)}
            if preset_pressure is not None:
                case = with_preset_pressure(case, preset_pressure)
            moved.append(_matched(base, modes(case, inlet_flow, tank_pressure)))
        table[name] = [
            (
                (up.frequency_hz - down.frequency_hz) / (2.0 * percent),
                (up.decay_rate - down.decay_rate) / (2.0 * percent),
            )
            for up, down in zip(*moved)
        ]
    return base, table


def slowest_decay_rate(params, inlet_flows):
    """
    Return the slowest decay rate -Re(lambda) [1/s] of the linear modes at the steady states.

    Every eigenvalue of the Jacobian at the steady state of each inlet flow [m^3/s]
    counts, oscillatory or not; negative: a mode that grows (the valve is unstable).
    Raises SteadyStateError where a steady state cannot be found.
    """
    return min(
        float(np.min(-np.linalg.eigvals(jacobian(params, equilibrium, flow)).real))
        for flow, equilibrium in ((q, steady_state(params, q, stable=False)) for q in inlet_flows)
    )
