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
Exact steady state of the valve for a constant inlet flow.

At steady state every chamber's net flow and every net force vanish (Eqs. 1-7
with all time derivatives zero). The solution is found by Newton's method
(valve_sim.core.newton: damped Newton, scipy's hybr only where it fails) on those
balances, started from an estimate that follows the valve's own logic (poppet force
balance -> p_s, main-valve force balance -> p_p, pilot flow -> p_c and y, the rest
through the main valve). If that fails, Newton restarts from a pseudo-transient: the
model integrated with a small supply volume V_s and added valve damping, which change
how fast the valve settles but not where. Either valve may rest on its seat or end
stop; then its position is fixed there and its force balance is replaced by the
contact condition.

A tank pressure p_t [Pa, gauge] enters the balances as it enters the model; the
estimates are made relative to the tank and shifted by it. Since every force and flow
depends on pressures relative to the tank, a steady state at p_t has the pressures of
the one at the tank at ambient, each raised by p_t (docs/model.md, "Back pressure");
the solver does not assume it, the tests check it.

Faults (valve_sim.core.faults) change the balances as they change the model; a stuck
main valve is solved as free (it then sticks where the solution puts it), and friction
is left out: the frictionless rest state is one of the states friction holds.

Over 400 lines because the steady state, the cracking point and the preset share
the balances, their scaling and the design estimate; the static characteristic built
on them lives in valve_sim.core.steady_curve.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import IntegrationError, ParameterError, SteadyStateError
from valve_sim.core.faults import FaultSet, HEALTHY
from valve_sim.core.integrator import advance
from valve_sim.core.jit import jit
from valve_sim.core.limits import inlet_flow_problem, state_problem, tank_pressure_problem
from valve_sim.core.model import (
    derivatives,
    flows,
    net_forces,
    P_C,
    P_M,
    P_P,
    P_S,
    X,
    Y,
)
from valve_sim.core.newton import find_root
from valve_sim.core.parameters import SPECS, validate
from valve_sim.core.stability import growing_mode


PSEUDO_TRANSIENT_SUPPLY_VOLUME = 2e-5  # [m^3] small enough to settle within PSEUDO_TRANSIENT_TIME
PSEUDO_TRANSIENT_TIME = 0.3  # [s]
PSEUDO_TRANSIENT_STEP = 5e-6  # [s]
PSEUDO_TRANSIENT_DAMPING = (200.0, 50.0)  # [N s/m] added to main valve and poppet
TOLERANCE = 1e-10  # relative residual of flows and forces
TINY_FLOW_TOLERANCE = 1e-7  # the same relative to a tiny inlet flow: 1e-17 m^3/s at 1e-10
# [m^3/s] below it double precision cannot resolve the flow balances (a poppet open by
# 1e-15 m next to 6 MPa pressures): steady_state extrapolates from above it.
TINY_FLOW = 1e-12


@jit
def _balances(state, inlet_flow, c, tank_pressure):
    """Net flows into chambers s, m, p, c [m^3/s] and net forces on x, y [N], in one call."""
    rates = derivatives(state, inlet_flow, c, tank_pressure)
    force_x, force_y = net_forces(state, c, tank_pressure)
    return (
        rates[P_S] / c.supply_compliance_inv,
        rates[P_M] / c.intermediate_compliance_inv,
        rates[P_P] / c.pilot_compliance_inv,
        rates[P_C] / c.poppet_chamber_compliance_inv,
        force_x,
        force_y,
    )


def _residuals(state, inlet_flow, c, flow_scale, force_scale, tank_pressure):
    """Scaled flow imbalances of chambers s, m, p, c and net forces on x and y."""
    residuals = np.array(_balances(state, inlet_flow, c, tank_pressure))
    residuals[:4] /= flow_scale
    residuals[4:] /= force_scale
    return residuals


def _newton(guess, inlet_flow, c, fixed_x, fixed_y, tank_pressure, tolerance, tiny_flow=False):
    """
    Solve the balances from guess to tolerance, (state, max relative residual).

    A valve whose fixed position is not None rests there.

    Flows are scaled by at least 1e-7 m^3/s and a free position by its stroke; with
    tiny_flow, by the inlet flow and the guessed position (a poppet open by 1e-15 m at
    1e-15 m^3/s is lost in the usual scales).
    """
    pressure_scale = max(guess[P_S] - tank_pressure, 1e5)
    flow_scale = inlet_flow if tiny_flow else max(inlet_flow, 1e-7)
    force_scale = c.back_area * pressure_scale
    free, equations, scale = [P_S, P_M, P_P, P_C], [0, 1, 2, 3], [pressure_scale] * 4
    for index, equation, fixed, stroke in (
        (X, 4, fixed_x, c.main_valve_stroke),
        (Y, 5, fixed_y, c.poppet_stroke),
    ):
        if fixed is None:
            free.append(index)
            equations.append(equation)
            small = tiny_flow and 0.0 < guess[index] < stroke
            scale.append(guess[index] if small else stroke)
    scale = np.array(scale)

    def compose(u):
        state = np.zeros(8)
        state[X] = fixed_x or 0.0
        state[Y] = fixed_y or 0.0
        state[free] = u * scale
        return state

    def residual(u):
        state = compose(u)
        return _residuals(state, inlet_flow, c, flow_scale, force_scale, tank_pressure)[equations]

    solution = find_root(residual, np.asarray(guess)[free] / scale, tolerance)
    return compose(solution.x), solution.residual


def _contacts(position, stroke):
    """Contact modes to try for one valve, the one the pseudo-transient suggests first."""
    modes = [None, 0.0, stroke]
    likely = 0.0 if position <= 0.0 else stroke if position >= stroke else None
    modes.remove(likely)
    return [likely] + modes


def _contact_is_consistent(state, c, tank_pressure):
    """Check that a valve inside its stroke is free and one at a stop is pushed into it."""
    force_x, force_y = net_forces(state, c, tank_pressure)
    slack = 1e-9 * c.back_area * max(state[P_S] - tank_pressure, 1.0)
    for position, force, stroke in (
        (state[X], force_x, c.main_valve_stroke),
        (state[Y], force_y, c.poppet_stroke),
    ):
        if position < 0.0 or position > stroke:
            return False
        if position == 0.0 and force > slack or position == stroke and force < -slack:
            return False
    return True


def _above_tank(state, tank_pressure):
    """Return a state estimated relative to the tank with its pressures raised by tank_pressure."""
    state[[P_S, P_M, P_P, P_C]] += tank_pressure
    return state


def _estimate(inlet_flow, c):
    """Open-valve estimate of the steady state from the valve's design logic, tank at 0."""
    state = np.zeros(8)
    p_s = c.pilot_spring_stiffness * c.pilot_spring_preload / c.rod_area
    p_m = 0.6 * p_s
    p_p = (
        c.supply_force_area * p_s
        + c.intermediate_force_area * p_m
        - c.main_spring_stiffness * c.main_spring_preload
    ) / c.back_area
    state[[P_S, P_M, P_P, P_C]] = p_s, p_m, min(max(p_p, 0.0), p_s), 0.0
    q_n = flows(state, c)[2]
    p_c = max(state[P_P] - (q_n / max(c.damping_orifice_gain, 1e-30)) ** 2, 0.1 * state[P_P])
    state[P_C] = p_c
    q_pilot = min(q_n + c.rod_leakage_conductance * (p_s - p_c), inlet_flow)
    state[Y] = min(q_pilot / (c.poppet_gain * np.sqrt(max(p_c, 1.0))), c.poppet_stroke)
    q_main = inlet_flow - q_pilot
    state[X] = min(
        max(q_main, 0.0) / (c.second_throttle_gain * np.sqrt(max(p_m, 1.0))), c.main_valve_stroke
    )
    return state


def _pilot_opening_estimate(inlet_flow, c):
    """
    Estimate for a flow the pilot alone passes, barely open (tank at 0): a tiny flow's limit.

    All chambers at the pilot's opening pressure k_p y_0 / A_s, the main valve seated,
    the poppet open just enough for the flow.
    """
    state = np.zeros(8)
    state[[P_S, P_M, P_P, P_C]] = c.pilot_spring_stiffness * c.pilot_spring_preload / c.rod_area
    state[Y] = inlet_flow / (c.poppet_gain * np.sqrt(state[P_C]))
    return state


def _pseudo_transient(params, inlet_flow, c, tank_pressure):
    """State after integrating a fast-settling, damped copy of the model from the empty valve."""
    fast = c._replace(
        supply_compliance_inv=params['bulk_modulus'] / PSEUDO_TRANSIENT_SUPPLY_VOLUME,
        main_valve_damping=c.main_valve_damping + PSEUDO_TRANSIENT_DAMPING[0],
        pilot_poppet_damping=c.pilot_poppet_damping + PSEUDO_TRANSIENT_DAMPING[1],
    )
    state = empty_valve(tank_pressure)
    steps = int(round(PSEUDO_TRANSIENT_TIME / PSEUDO_TRANSIENT_STEP))
    try:
        advance(
            state, np.full(steps, float(inlet_flow)), fast, PSEUDO_TRANSIENT_STEP,
            tank_pressures=tank_pressure,
        )
    except IntegrationError as error:
        raise SteadyStateError(f'no steady state at {inlet_flow:g} m^3/s: {error}') from error
    return state


def _solve_from(guess, inlet_flow, c, tank_pressure, tiny_flow=False):
    """
    Newton from guess over the contact modes; (state, residual), state None if none fits.

    tiny_flow: flows scaled by the inlet flow itself (see _newton), where rounding of
    the 6 MPa pressures limits the relative residual to TINY_FLOW_TOLERANCE.
    """
    tolerance = TINY_FLOW_TOLERANCE if tiny_flow else TOLERANCE
    best = (None, np.inf)
    for fixed_x in _contacts(guess[X], c.main_valve_stroke):
        for fixed_y in _contacts(guess[Y], c.poppet_stroke):
            candidate, error = _newton(
                guess, inlet_flow, c, fixed_x, fixed_y, tank_pressure, tolerance, tiny_flow
            )
            if error < tolerance and _contact_is_consistent(candidate, c, tank_pressure):
                return candidate, error
            best = (None, min(best[1], error))
    return best


def steady_coefficients(params, faults):
    """
    Coefficients of the valve's balances.

    With the faults' terms, the main valve free, no friction, and no supply limit
    (the supply's relief is no path of the valve; steady_state checks the limit).
    """
    return coefficients(
        params,
        replace(
            faults,
            main_valve_stuck=False,
            bearing_coulomb_friction=0.0,
            bearing_static_friction=0.0,
        ),
    )._replace(supply_pressure_limit=np.inf)


def empty_valve(tank_pressure=0.0):
    """Return the closed valve without inflow: every chamber at the tank's pressure."""
    state = np.zeros(8)
    state[[P_S, P_M, P_P, P_C]] = tank_pressure
    return state


def steady_state(
    params: Mapping[str, float], inlet_flow: float, faults: FaultSet = HEALTHY,
    tank_pressure: float = 0.0, stable: bool = True,
) -> np.ndarray:
    """
    Exact steady state [8-array] of the valve for a constant inlet flow [m^3/s].

    params: validated parameter dict; faults: FaultSet; tank_pressure: p_t [Pa,
    gauge], the tank's (return line's) pressure. inlet_flow = 0 gives the empty,
    closed valve, its chambers at the tank's pressure; any flow above 0, however
    small, the valve held at its pilot's opening pressure above the tank. Raises
    SteadyStateError when the flow or the tank pressure is not a valid
    input (above max_inlet_flow), when no consistent steady state is found, or when
    the steady state is beyond the physical limits (burst_pressure) or the bench's
    supply_pressure_limit: a steady state is never an impossible state. stable: refuse
    an equilibrium that is linearly unstable too (core/stability.py: the valve does not
    rest there); False returns it, for a run's start (docs/model.md).
    """
    problem = inlet_flow_problem(inlet_flow, params['max_inlet_flow']) or tank_pressure_problem(
        tank_pressure, params['burst_pressure']
    )
    if problem:
        raise SteadyStateError(f'no steady state: {problem}')
    if inlet_flow == 0.0:
        return empty_valve(tank_pressure)
    if inlet_flow < TINY_FLOW:
        # The balances are linear in the flow down here (every orifice laminar, the
        # poppet opening proportional to it): extrapolate from two resolvable flows.
        low = steady_state(params, TINY_FLOW, faults, tank_pressure, stable)
        high = steady_state(params, 2.0 * TINY_FLOW, faults, tank_pressure, stable)
        state = low + (high - low) * (inlet_flow - TINY_FLOW) / TINY_FLOW
        state[Y] = max(state[Y], 0.0)
        return state
    c = steady_coefficients(params, faults)
    estimate = _above_tank(_estimate(inlet_flow, c), tank_pressure)
    state, error = _solve_from(estimate, inlet_flow, c, tank_pressure)
    if state is None:
        transient = _pseudo_transient(params, inlet_flow, c, tank_pressure)
        state, error = _solve_from(transient, inlet_flow, c, tank_pressure)
    if state is None:
        opening = _above_tank(_pilot_opening_estimate(inlet_flow, c), tank_pressure)
        state, error = _solve_from(opening, inlet_flow, c, tank_pressure, True)
    if state is None:
        raise SteadyStateError(
            f'no consistent steady state at inlet flow {inlet_flow:g} m^3/s '
            + (f'and tank pressure {tank_pressure:g} Pa ' if tank_pressure else '')
            + f'(smallest relative residual {error:.2e}); check the parameters'
        )
    problem = state_problem(state, params['burst_pressure'])
    if problem:
        raise SteadyStateError(f'the steady state at {inlet_flow:g} m^3/s is refused: {problem}')
    growing = growing_mode(c, state, inlet_flow, tank_pressure) if stable else None
    if growing is not None:
        # Every balance holds, yet the valve does not rest there: any disturbance grows.
        raise SteadyStateError(
            f'no stable steady state at inlet flow {inlet_flow:g} m^3/s'
            + (f' (faults: {faults.describe()})' if faults.active() else '')
            + f': the only equilibrium found (p_s = {state[P_S]:.6g} Pa) is unstable, a mode '
            f'at {abs(growing.imag) / (2 * np.pi):.4g} Hz grows at {growing.real:.3g} 1/s'
        )
    if 0.0 < params['supply_pressure_limit'] < state[P_S]:
        raise SteadyStateError(
            f'the valve passes {inlet_flow:g} m^3/s only at p_s = {state[P_S]:.6g} Pa, above '
            f"supply_pressure_limit = {params['supply_pressure_limit']:g} Pa"
            + (f' (faults: {faults.describe()})' if faults.active() else '')
        )
    return state


def _cracking_problem(state, error, poppet_stroke):
    """
    Why a solution of the cracking balances is no cracking point (None if it is one).

    The residual and the poppet's place decide, not a solver's progress flag: with
    xtol 1e-13 hybr (find_root's fallback) often sits on the root (residual ~1e-16)
    yet reports that it is "not making good progress".
    """
    if not error <= TOLERANCE:  # also NaN
        return (
            f'the pilot-stage balances have no solution near the design estimate '
            f'(relative residual {error:.2e} where the solver stopped); check the parameters'
        )
    if not state[Y] < poppet_stroke:
        return (
            f'the poppet would have to open {state[Y]:.4g} m, beyond its stroke y_max = '
            f'{poppet_stroke:g} m: it reaches its end stop before the main valve lifts off'
        )
    if not state[Y] > 0.0:
        return (
            f'the poppet would have to be closed (y = {state[Y]:.4g} m): the main valve '
            'lifts off before the pilot opens'
        )
    return None


def cracking_pressure(
    params: Mapping[str, float], faults: FaultSet = HEALTHY, tank_pressure: float = 0.0
) -> float:
    """
    Supply pressure [Pa, gauge] at which the main valve lifts off its seat (steady state).

    faults: FaultSet (e.g. a weakened pilot spring lowers it); tank_pressure: p_t [Pa,
    gauge], the back pressure, which raises it by p_t (docs/model.md, "Back pressure").

    At that point the main valve rests at x = 0 with zero net force, no flow
    passes the main throttles (so p_m = p_s) and all inlet flow goes through the
    pilot stage. Solved by Newton's method on the pilot-chamber and poppet-chamber
    balances and the two force balances, in p_s, p_p, p_c and y.
    """
    c = steady_coefficients(params, faults)
    guess = _above_tank(_estimate(1e-5, c), tank_pressure)
    pressure_scale = max(guess[P_S] - tank_pressure, 1e5)
    scale = np.array([pressure_scale, pressure_scale, pressure_scale, c.poppet_stroke])

    def compose(u):
        state = np.zeros(8)
        state[[P_S, P_P, P_C, Y]] = u * scale
        state[P_M] = state[P_S]
        return state

    def residual(u):
        return _residuals(
            compose(u), 0.0, c, 1e-5, c.back_area * pressure_scale, tank_pressure
        )[[2, 3, 4, 5]]

    solution = find_root(residual, guess[[P_S, P_P, P_C, Y]] / scale, TOLERANCE)
    state = compose(solution.x)
    problem = _cracking_problem(state, solution.residual, c.poppet_stroke)
    if problem:
        raise SteadyStateError(f'no cracking point found: {problem}')
    return float(state[P_S])


def preset_preload(params, pressure):
    """
    Return (pilot spring preload y_0 [m], cracking pressure [Pa]) for the preset pressure [Pa].

    What a technician does with the adjusting screw: y_0 that makes the main valve
    crack at pressure, and the cracking pressure that y_0 gives (within 1e-9 of it),
    with the tank at ambient: the preset is the valve's setting, the pressure above
    the tank at which it cracks, whatever the back pressure in a circuit.
    The cracking pressure rises almost linearly with y_0 (poppet balance
    A_s p_s ~ k_p (y + y_0)), so a few secant steps from that estimate converge;
    raises ParameterError if the preload would leave its limits.
    """
    spec = SPECS['pilot_spring_preload']
    trial = dict(params)

    def error(preload):
        trial['pilot_spring_preload'] = preload
        return cracking_pressure(trial) - pressure

    slope = coefficients(params).rod_area / params['pilot_spring_stiffness']  # dy_0/dp [m/Pa]
    y0 = params['pilot_spring_preload']
    e0 = error(y0)
    for _ in range(20):
        y1 = y0 - e0 * slope
        if not spec.minimum <= y1 <= spec.maximum:
            raise ParameterError(
                f'preset pressure {pressure:g} Pa needs pilot_spring_preload (y_0) = {y1:g} m, '
                f'outside its limits [{spec.minimum:g}, {spec.maximum:g}] m'
            )
        trial['pilot_spring_preload'] = y1
        cracking = cracking_pressure(trial)
        e1 = cracking - pressure
        if abs(e1) < 1e-9 * pressure:
            return validate(trial)['pilot_spring_preload'], cracking
        if e1 != e0:
            slope = (y1 - y0) / (e1 - e0)
        y0, e0 = y1, e1
    raise SteadyStateError(f'could not find a preload for a cracking pressure of {pressure:g} Pa')


def preload_for_cracking_pressure(params, pressure):
    """Pilot spring preload y_0 [m] that makes the main valve crack at pressure [Pa]."""
    return preset_preload(params, pressure)[0]


def with_preset_pressure(params, pressure):
    """
    Copy of params whose pilot spring preload y_0 makes the main valve crack at pressure [Pa].

    The preset as one concept: parameter files, --preset-pressure, valve_node's
    preset_pressure and the study's held preset all mean this cracking pressure.
    """
    return {**params, 'pilot_spring_preload': preload_for_cracking_pressure(params, pressure)}
