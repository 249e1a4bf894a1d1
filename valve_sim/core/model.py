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
Equations (1)-(16) of the paper: the right-hand side of the valve model.

State vector (SI units, pressures gauge, i.e. relative to the ambient pressure):

    index  name                        symbol  unit
    0      supply_pressure             p_s     Pa
    1      intermediate_pressure       p_m     Pa
    2      pilot_pressure              p_p     Pa
    3      poppet_chamber_pressure     p_c     Pa
    4      main_valve_displacement     x       m   (0 = seated, positive opens)
    5      main_valve_velocity         x_dot   m/s
    6      poppet_displacement         y       m   (0 = seated, positive opens)
    7      poppet_velocity             y_dot   m/s

Departures from the printed equations, each explained in docs/model.md:
- alpha_s of Eq. (8) carries the factor 1/2 that the derivation gives.
- Every area on which a chamber's pressure pushes a valve is the area by which the
  valve's motion sweeps that chamber's volume: A_m1 = alpha_s in Eq. (1), a swept
  term alpha_m x_dot in Eq. (2), and the poppet chamber's net area
  A_c = pi/4 (d_v^2 - d_s^2) in Eqs. (4) and (7) (zero for the paper's balanced
  poppet, d_v = d_s).
- Every turbulent orifice law sgn(dp) sqrt(|dp|) turns laminar (a cubic with
  finite slope) below |dp| = dp_tr, and is exact above it, so that zero-flow and
  closed-valve states stay stable under fixed-step RK4.
- Eq. (12) is normalised by the upstream pressure max(p_s, p_p), which equals the
  printed p_s in forward flow and stays bounded in reverse flow or at zero pressure,
  and never by less than the drop |p_s - p_p| (z within the fit's 0..1).
- Seats and end stops: a valve at a stop that is pushed into it does not move.
- The supply may be pressure-limited: at supply_pressure_limit (if set) its own relief
  (the bench pump's) takes the inflow the valve does not pass, so p_s stops rising there.

The tank pressure p_t [Pa, gauge] is an input beside the inlet flow (0: the tank at ambient,
the paper's case). It acts wherever the tank does: the flows to tank q_m2 (Eq. 11) and q_p
(Eq. 15), the seat leakage, the flow force on the poppet, and the tank's pressure on the
tank-facing areas A_t (main valve) and A_v (poppet). Eq. (12) is normalised by the upstream
pressure above the tank. So every force and flow depends on pressures relative to the tank
only: a constant back pressure shifts every pressure of a steady state by p_t, and the
cracking pressure with it (docs/model.md, "Back pressure"). relief_flows() is the flow the
valve passes to the tank. With p_t = 0 every term is computed exactly as without it.

The kernels take the parameters as Coefficients, the derived constants of Eqs. (5), (8),
(9), (16), which valve_sim.core.coefficients computes from a parameter dict. Coefficients
itself stays defined here: numba's kernel cache records it by module and name.

Valve faults (valve_sim.core.faults, docs/faults.md) enter as physical terms and nowhere
else: orifice blockage and spring weakening scale K_c, K_b and k_p in
coefficients.coefficients(); friction (bearing_friction), seat leakage (seat_leakage_flow)
and a stuck main valve (main_valve_free) act in derivatives() here. With no fault every
term is skipped, so the healthy model is computed exactly as without them.

fastest_chamber_rate() tells the integrator when a fixed step must be split.

About 400 lines on purpose: the paper's equations 1-16 in one module, the functions
numba compiles into one kernel together.
"""

from collections import namedtuple
import math

import numpy as np
from valve_sim.core.jit import jit


STATE_NAMES = (
    'supply_pressure',
    'intermediate_pressure',
    'pilot_pressure',
    'poppet_chamber_pressure',
    'main_valve_displacement',
    'main_valve_velocity',
    'poppet_displacement',
    'poppet_velocity',
)
P_S, P_M, P_P, P_C, X, X_DOT, Y, Y_DOT = range(8)

# Karnopp stick band of the bearing friction (numerical choices, docs/faults.md): below
# STICK_VELOCITY [m/s] the main valve counts as sticking, and static friction up to F_st
# holds it and brings its residual velocity to zero with the time constant
# STICK_RELAXATION_TIME [s] (RK4-stable for every allowed step size, <= 1e-4 s).
STICK_VELOCITY = 1e-3
STICK_RELAXATION_TIME = 1e-4

# Parameters the kernels take unchanged, under their own names: masses m_m, m_p,
# dampings c_m, c_p, springs k_m, x_0, k_p, y_0 and strokes x_max, y_max (SI units).
MECHANICS = (
    'main_valve_mass', 'main_valve_damping', 'main_spring_stiffness', 'main_spring_preload',
    'main_valve_stroke', 'pilot_poppet_mass', 'pilot_poppet_damping', 'pilot_spring_stiffness',
    'pilot_spring_preload', 'poppet_stroke',
)

# Derived constants of Eqs. (5), (8), (9), (16), in the form the kernels use.
Coefficients = namedtuple(
    'Coefficients',
    (
        'supply_compliance_inv',  # beta / V_s              [Pa/m^3]
        'intermediate_compliance_inv',  # beta / V_m              [Pa/m^3]
        'pilot_compliance_inv',  # beta / V_p              [Pa/m^3]
        'poppet_chamber_compliance_inv',  # beta / V_c             [Pa/m^3]
        # Each area below is both a force area and a swept area (docs/model.md, "Areas").
        'rod_area',  # A_s = pi/4 d_s^2: p_s on the rod, swept out of V_s  [m^2]
        'back_area',  # A_p = pi/4 d_p^2: p_p on the main valve, swept out of V_p  [m^2]
        'supply_force_area',  # alpha_s, Eq. (8) = A_m1, swept out of V_s  [m^2]
        'intermediate_force_area',  # alpha_m, Eq. (8), swept out of V_m  [m^2]
        'poppet_chamber_area',  # A_c = pi/4 (d_v^2 - d_s^2), swept out of V_c  [m^2]
        'tank_force_area',  # A_t = A_p - alpha_s - alpha_m: the tank on the main valve  [m^2]
        'seat_area',  # A_v = A_s + A_c = pi/4 d_v^2: the tank (spring side) on the poppet  [m^2]
        'flow_force_gain',  # K_f, Eq. (9)            [m]
        'first_throttle_gain',  # pi C_d D_1 sqrt(2/rho)  [m^2/s/sqrt(Pa) per m]
        'second_throttle_gain',  # pi C_d D_2 sqrt(2/rho)
        'first_throttle_clearance',  # h                       [m]
        'bearing_gain',  # K_b, Eq. (16)           [m^3/s/sqrt(Pa)]
        'bearing_k1',
        'bearing_k2',
        'bearing_k3',  # K_1..K_3, Eq. (12)
        'damping_orifice_gain',  # K_c, Eq. (16)           [m^3/s/sqrt(Pa)]
        'rod_leakage_conductance',  # K_s, Eq. (16)           [m^3/s/Pa]
        'poppet_gain',  # K_p, Eq. (16)           [m^2/s/sqrt(Pa)]
        *MECHANICS,  # as in the parameter dict
        'transition_pressure',  # dp_tr                   [Pa]
        'burst_pressure',  # p_burst, a physical limit  [Pa]
        'supply_pressure_limit',  # p_s,max (inf: none)     [Pa]
        'cavitation_pressure',  # p_v - p_amb: the vapour pressure, gauge  [Pa]
        'coulomb_friction',  # F_c, fault               [N]
        'static_friction',  # max(F_st, F_c), fault    [N]
        'seat_leakage_gain',  # K_l, fault             [m^3/s/sqrt(Pa)]
        'main_valve_free',  # 0.0 if stuck (fault), else 1.0
    ),
)

# [Pa, absolute] water's vapour pressure p_v at 20 degC (IAPWS-IF97 saturation line: 2.339
# kPa). Below it a chamber's liquid gives way to a vapour cavity (cavitation_share).
VAPOUR_PRESSURE = 2339.0
# [Pa] Delta: the width over which a cavity's pressure falls below p_v as it grows, the
# effective bulk modulus beta exp((p - p_v) / Delta) (docs/model.md, "Cavitation"). Small
# against p_v: a cavity as large as its chamber holds the pressure at p_v - Delta
# ln(1 + beta / Delta), 1.7 kPa below p_v at beta = 2.2 GPa, above absolute zero.
CAVITATION_WIDTH = 100.0

# The fault terms of Coefficients (coefficients.with_faults) and their values in a healthy valve.
HEALTHY_TERMS = {
    'coulomb_friction': 0.0,
    'static_friction': 0.0,
    'seat_leakage_gain': 0.0,
    'main_valve_free': 1.0,
}


@jit
def orifice_root(dp, transition):
    """
    sgn(dp) sqrt(|dp|) [sqrt(Pa)], with a laminar region for |dp| < transition.

    Exactly the paper's turbulent law for |dp| >= transition; below it the cubic
    sqrt(tr) (1.25 r - 0.25 r^3), r = dp / tr, which matches it in value and slope
    at |dp| = tr and has the finite slope 1.25 / sqrt(tr) at zero. One square root
    serves both regions (sqrt(|dp|) or sqrt(tr)), and r is a product with 1 / tr,
    one division for all orifices of an evaluation: the vectorised kernel computes
    both regions for every orifice (docs/speed.md).
    """
    magnitude = abs(dp)
    root = math.sqrt(max(magnitude, transition))
    if magnitude >= transition:
        return math.copysign(root, dp)
    r = dp * (1.0 / transition)
    return root * r * (1.25 - 0.25 * r * r)


@jit
def orifice_root_slope(dp, transition):
    """Return the slope of orifice_root at dp [1/sqrt(Pa)]: a unit orifice's conductance."""
    magnitude = abs(dp)
    root = math.sqrt(max(magnitude, transition))
    if magnitude >= transition:
        return 0.5 / root
    r = dp / transition
    return (1.25 - 0.75 * r * r) / root


@jit
def bearing_upstream(p_s, p_p, tank_pressure, transition):
    """
    Return the pressure [Pa] that normalises Eq. (12): the upstream one above the tank.

    max(p_s, p_p) - p_t, and never below the drop |p_s - p_p| itself, so that the
    fit's z = |p_s - p_p| / upstream stays within its range 0..1: the downstream
    chamber below the tank (p_t stepped above it) would make z, and the cubic, unbounded
    (a bearing flow of 0.9 m^3/s, a 1e9 1/s pressure mode after a 10 MPa tank step).
    """
    return max(p_s - tank_pressure, p_p - tank_pressure, abs(p_s - p_p), transition)


@jit
def cavitation_share(pressure, c):
    """
    Return beta_eff / beta of a chamber at pressure [Pa, gauge]: 1 at and above p_v.

    Below the vapour pressure (c.cavitation_pressure, gauge) the chamber's liquid is at
    p_v and a vapour cavity takes the volume the chamber gives up: beta_eff = beta exp((p -
    p_v) / Delta) (CAVITATION_WIDTH), so that the pressure stays just below p_v however
    large the cavity, and the cavity collapses when the chamber fills again. Exactly 1
    above p_v: a run that stays there is computed as without it. It is dp / dp*
    (chamber_pressure).
    """
    if pressure < c.cavitation_pressure:
        return math.exp((pressure - c.cavitation_pressure) * (1.0 / CAVITATION_WIDTH))
    return 1.0


def cavity_volumes(pressures, compliances_inv, cavitation_pressure):
    """
    Return each chamber's vapour cavity [m^3] at pressures [Pa, gauge] (arrays alike).

    D = (V Delta / beta) (exp((p_v - p) / Delta) - 1) below p_v (compliances_inv: beta / V),
    0 above: the volume the chamber has given up below p_v (chamber_pressure), which
    the volume balance counts (invariants.stored_volumes).
    """
    below = np.minimum(np.asarray(pressures, dtype=float) - cavitation_pressure, 0.0)
    exponent = np.minimum(-below / CAVITATION_WIDTH, 700.0)  # a diverged state: no overflow
    return CAVITATION_WIDTH / np.asarray(compliances_inv) * np.expm1(exponent)


@jit
def chamber_pressure(liquid, c):
    """
    Return a chamber's pressure [Pa, gauge] from its liquid pressure p* [Pa, gauge].

    p* is the pressure the chamber's liquid would have at the constant beta: p* = p_v -
    beta D / V with a cavity D (cavity_volumes), and the pressure p = p_v - Delta ln(1 +
    (p_v - p*) / Delta) below p_v (c.cavitation_pressure, gauge), p* itself above it: the
    effective bulk modulus beta exp((p - p_v) / Delta) integrated. The integrator moves
    p*, linear in the chamber's stored volume, where p would freeze: a step that
    overshoots below p_v in p is a cavity of exp(overshoot / Delta) its true size.
    """
    if liquid < c.cavitation_pressure:
        return c.cavitation_pressure - CAVITATION_WIDTH * math.log1p(
            (c.cavitation_pressure - liquid) * (1.0 / CAVITATION_WIDTH)
        )
    return liquid


@jit
def liquid_pressure(pressure, c):
    """Return a chamber's liquid pressure p* [Pa, gauge] at pressure [Pa, gauge] (its inverse)."""
    if pressure < c.cavitation_pressure:
        depth = min((c.cavitation_pressure - pressure) * (1.0 / CAVITATION_WIDTH), 700.0)
        return c.cavitation_pressure - CAVITATION_WIDTH * math.expm1(depth)
    return pressure


@jit
def pressure_state(state, c):
    """Return the 8-tuple state with each chamber's pressure for its liquid pressure p*."""
    return (
        chamber_pressure(state[P_S], c), chamber_pressure(state[P_M], c),
        chamber_pressure(state[P_P], c), chamber_pressure(state[P_C], c),
        state[X], state[X_DOT], state[Y], state[Y_DOT],
    )


@jit
def liquid_state(state, c):
    """Return the 8-tuple state with each chamber's liquid pressure p* for its pressure."""
    return (
        liquid_pressure(state[P_S], c), liquid_pressure(state[P_M], c),
        liquid_pressure(state[P_P], c), liquid_pressure(state[P_C], c),
        state[X], state[X_DOT], state[Y], state[Y_DOT],
    )


@jit
def fastest_chamber_rate(state, c, tank_pressure=0.0):
    """
    Return a bound [1/s] on the fastest decay rate of the four chamber pressures.

    state: as derivatives() takes it (liquid pressures p*); tank_pressure: p_t [Pa,
    gauge], where the flows to tank go.

    Near the state the pressures relax as d p / dt = -C G p, C = beta / V of each
    chamber, G the orifices' conductances |dq / dp|. C G is similar to the symmetric
    C^1/2 G C^1/2, whose Gershgorin rows bound its eigenvalues: a chamber's own rate
    beta/V * sum |dq/dp| (the Jacobian's diagonal) plus its coupling to its
    neighbours. The coupling matters where two small chambers share a wide orifice:
    the pilot and poppet chambers of the closed, empty valve (every orifice laminar)
    relax 1.8 times faster than either alone. A chamber between two wide orifices
    with small drops (the one between the main throttles at a low preset and a
    large flow) is stiff too. Fixed-step RK4 needs step * rate below 2.79
    (integrator.rk4_steps). A chamber below the vapour pressure has beta_eff / V for C
    (dp/dp* = cavitation_share): its p* moves at beta / V times its inflow, whose
    conductances see p: a cavity itself adds no stiffness in p*.
    """
    real = pressure_state(state, c)
    p_s, p_m, p_p, p_c = real[P_S], real[P_M], real[P_P], real[P_C]
    x = min(max(real[X], 0.0), c.main_valve_stroke)
    y = min(max(real[Y], 0.0), c.poppet_stroke)
    tr = c.transition_pressure
    throttle_1 = c.first_throttle_gain * (x + c.first_throttle_clearance) * orifice_root_slope(
        p_s - p_m, tr
    )
    throttle_2 = c.second_throttle_gain * x * orifice_root_slope(p_m - tank_pressure, tr)
    orifice = c.damping_orifice_gain * orifice_root_slope(p_p - p_c, tr)
    poppet = c.poppet_gain * y * orifice_root_slope(p_c - tank_pressure, tr)
    upstream = bearing_upstream(p_s, p_p, tank_pressure, tr)
    z = abs(p_s - p_p) / upstream
    bearing = c.bearing_gain * (
        c.bearing_k1 + z * (2.0 * c.bearing_k2 + 3.0 * z * c.bearing_k3)
    ) / math.sqrt(upstream)
    bearing, leak = abs(bearing), c.rod_leakage_conductance
    seat = c.seat_leakage_gain * orifice_root_slope(p_s - tank_pressure, tr)  # worn seat (fault)
    c_s, c_m = c.supply_compliance_inv, c.intermediate_compliance_inv
    c_p, c_c = c.pilot_compliance_inv, c.poppet_chamber_compliance_inv
    if min(p_s, p_m, p_p, p_c) < c.cavitation_pressure:
        c_s, c_m = c_s * cavitation_share(p_s, c), c_m * cavitation_share(p_m, c)
        c_p, c_c = c_p * cavitation_share(p_p, c), c_c * cavitation_share(p_c, c)
    k_sm, k_sp = math.sqrt(c_s * c_m), math.sqrt(c_s * c_p)  # couplings sqrt(C_i C_j)
    k_sc, k_pc = math.sqrt(c_s * c_c), math.sqrt(c_p * c_c)
    return max(
        c_s * (throttle_1 + bearing + leak + seat) + k_sm * throttle_1 + k_sp * bearing
        + k_sc * leak,
        c_m * (throttle_1 + throttle_2) + k_sm * throttle_1,
        c_p * (bearing + orifice) + k_sp * bearing + k_pc * orifice,
        c_c * (orifice + leak + poppet) + k_pc * orifice + k_sc * leak,
    )


@jit
def fastest_body_rate(state, c, tank_pressure=0.0):
    """
    Return a bound [1/s] on |lambda| of the two bodies' modes: each valve on its fluid springs.

    A valve's motion sweeps its chambers (Eqs. 1-4), whose pressures push it back: a
    spring beta A^2 / V per chamber, state-independent (the compliances are constant),
    beside its mechanical spring (and, for the poppet, the flow force's stiffness
    K_f (p_c - p_t)). omega^2 = sum of the springs / mass, plus the damping's rate c / m.
    fastest_chamber_rate() leaves these out: a 0.1 g main valve rings at 1.6e6 rad/s,
    16 x beyond RK4's limit at 10 us, while its chambers are slow.
    """
    c_s, c_m = c.supply_compliance_inv, c.intermediate_compliance_inv
    c_p, c_c = c.pilot_compliance_inv, c.poppet_chamber_compliance_inv
    main_springs = (
        c.back_area * c.back_area * c_p
        + c.supply_force_area * c.supply_force_area * c_s
        + c.intermediate_force_area * c.intermediate_force_area * c_m
        + c.main_spring_stiffness
    )
    main = (
        math.sqrt(main_springs / c.main_valve_mass) + c.main_valve_damping / c.main_valve_mass
    ) * c.main_valve_free
    poppet_springs = (
        c.rod_area * c.rod_area * c_s
        + c.poppet_chamber_area * c.poppet_chamber_area * c_c
        + c.pilot_spring_stiffness
        + c.flow_force_gain * abs(chamber_pressure(state[P_C], c) - tank_pressure)
    )
    poppet = (
        math.sqrt(poppet_springs / c.pilot_poppet_mass)
        + c.pilot_poppet_damping / c.pilot_poppet_mass
    )
    return max(main, poppet)


@jit
def flows(state, c, tank_pressure=0.0):
    """
    Flows of Eqs. (10)-(15) [m^3/s] as (q_m1, q_m2, q_n, q_c, q_s, q_p).

    q_m1 first main throttle p_s -> p_m, q_m2 second main throttle p_m -> tank,
    q_n hydrostatic bearings p_s -> p_p, q_c damping orifice p_p -> p_c,
    q_s rod clearance p_s -> p_c, q_p pilot poppet p_c -> tank; the tank at
    tank_pressure p_t [Pa, gauge]. Eq. (12) is normalised by the upstream pressure
    above the tank, max(p_s, p_p) - p_t: the bearing's flow depends on its pressure
    drop alone, and its fit holds at the supply's pressure above the tank.
    """
    p_s, p_m, p_p, p_c = state[P_S], state[P_M], state[P_P], state[P_C]
    x = min(max(state[X], 0.0), c.main_valve_stroke)
    y = min(max(state[Y], 0.0), c.poppet_stroke)
    tr = c.transition_pressure
    q_m1 = (
        c.first_throttle_gain * (x + c.first_throttle_clearance) * orifice_root(p_s - p_m, tr)
    )  # (10)
    q_m2 = c.second_throttle_gain * x * orifice_root(p_m - tank_pressure, tr)  # (11)
    upstream = bearing_upstream(p_s, p_p, tank_pressure, tr)
    z = abs(p_s - p_p) / upstream
    bearing = z * (c.bearing_k1 + z * (c.bearing_k2 + z * c.bearing_k3))
    q_n = math.copysign(1.0, p_s - p_p) * c.bearing_gain * math.sqrt(upstream) * bearing  # (12)
    q_c = c.damping_orifice_gain * orifice_root(p_p - p_c, tr)  # (13)
    q_s = c.rod_leakage_conductance * (p_s - p_c)  # (14)
    q_p = c.poppet_gain * y * orifice_root(p_c - tank_pressure, tr)  # (15)
    return q_m1, q_m2, q_n, q_c, q_s, q_p


@jit
def net_forces(state, c, tank_pressure=0.0):
    """
    Net forces on the main valve and the poppet [N], Eqs. (6)-(7) without inertia.

    The poppet's A_c p_c is the poppet chamber's pressure on the seat area less the
    rod's (zero for the paper's balanced poppet). The tank's pressure p_t
    (tank_pressure [Pa, gauge]) pushes the main valve open on A_t and the poppet shut
    on its seat area A_v (its spring chamber drains to the tank); the flow force
    grows with the poppet's pressure drop p_c - p_t.
    """
    p_s, p_m, p_p, p_c = state[P_S], state[P_M], state[P_P], state[P_C]
    x, x_dot, y, y_dot = state[X], state[X_DOT], state[Y], state[Y_DOT]
    force_x = (
        c.supply_force_area * p_s
        + c.intermediate_force_area * p_m
        + c.tank_force_area * tank_pressure
        - c.back_area * p_p
        - c.main_spring_stiffness * (x + c.main_spring_preload)
        - c.main_valve_damping * x_dot
    )
    force_y = (
        c.rod_area * p_s
        + c.poppet_chamber_area * p_c
        - c.seat_area * tank_pressure
        - c.flow_force_gain * max(y, 0.0) * (p_c - tank_pressure)
        - c.pilot_spring_stiffness * (y + c.pilot_spring_preload)
        - c.pilot_poppet_damping * y_dot
    )
    return force_x, force_y


@jit
def bearing_friction(velocity, force, c):
    """
    Friction force on the main valve [N] (fault), Karnopp's model with a stick band.

    Sliding (|x_dot| > STICK_VELOCITY): F_c against the motion. In the stick band the
    friction holds the valve against the other forces (force [N]) and brakes its residual
    velocity, as far as the static friction F_st reaches; a valve at rest under a force
    below F_st gets exactly zero acceleration.
    """
    if velocity > STICK_VELOCITY:
        return -c.coulomb_friction
    if velocity < -STICK_VELOCITY:
        return c.coulomb_friction
    hold = -force - c.main_valve_mass * velocity / STICK_RELAXATION_TIME
    return min(max(hold, -c.static_friction), c.static_friction)


@jit
def seat_leakage_flow(p_s, c, tank_pressure=0.0):
    """Leakage past a worn main seat, supply to tank [m^3/s] (fault): K_l sgn sqrt(p_s - p_t)."""
    return c.seat_leakage_gain * orifice_root(p_s - tank_pressure, c.transition_pressure)


@jit
def relief_flows(state, c, tank_pressure=0.0):
    """
    Flows into the tank [m^3/s] as (main stage q_m2, pilot stage q_p, seat leakage q_l).

    Their sum is the relief flow: all the valve passes to the tank at tank_pressure
    p_t [Pa, gauge]. The rod leakage q_s and the bearings' flow stay inside the valve
    (they join the pilot flow q_p). The inlet flow equals the relief flow plus the
    rate at which the valve stores volume: its chambers' compression
    sum(V_i / beta dp_i / dt) and the volume its bodies give the tank,
    -A_t x_dot + A_v y_dot (docs/model.md, "The flow balance").
    """
    _, q_m2, _, _, _, q_p = flows(state, c, tank_pressure)
    q_l = seat_leakage_flow(state[P_S], c, tank_pressure) if c.seat_leakage_gain > 0.0 else 0.0
    return q_m2, q_p, q_l


@jit
def stop_acceleration(position, velocity, force, mass, stroke):
    """
    Acceleration of a body between a seat at 0 and an end stop at stroke.

    At a stop, and pushed into it, the body does not accelerate: the stop takes the force.
    """
    if position <= 0.0 and velocity <= 0.0 and force <= 0.0:
        return 0.0
    if position >= stroke and velocity >= 0.0 and force >= 0.0:
        return 0.0
    return force / mass


@jit
def derivatives(state, inlet_flow, c, tank_pressure=0.0):
    """
    Return d(state)/dt (an 8-tuple, SI) at inlet flow q_in [m^3/s], Eqs. (1)-(7).

    state: the 8 states as a tuple or an array, each chamber's as its liquid pressure p*
    (liquid_state: the pressure itself at and above the vapour pressure); tank_pressure:
    p_t [Pa, gauge], the second input. A chamber's p* moves at beta / V times its net
    inflow, a cavity or not: its pressure is chamber_pressure(p*). A pure function of
    scalars, so that the integrator can evaluate it for many valves at once in vector
    registers.
    """
    real = pressure_state(state, c)  # the very state above the vapour pressure
    q_m1, q_m2, q_n, q_c, q_s, q_p = flows(real, c, tank_pressure)
    x_dot, y_dot = real[X_DOT] * c.main_valve_free, real[Y_DOT]
    supply = c.supply_compliance_inv * (
        inlet_flow - q_m1 - q_n - q_s - c.supply_force_area * x_dot - c.rod_area * y_dot
    )  # (1), A_m1 = alpha_s
    if c.seat_leakage_gain > 0.0:
        supply -= c.supply_compliance_inv * seat_leakage_flow(real[P_S], c, tank_pressure)
    if real[P_S] >= c.supply_pressure_limit and supply > 0.0:
        supply = 0.0  # the supply's relief takes the rest of the inflow
    intermediate = c.intermediate_compliance_inv * (
        q_m1 - q_m2 - c.intermediate_force_area * x_dot
    )  # (2) with its swept term
    pilot = c.pilot_compliance_inv * (q_n - q_c + c.back_area * x_dot)  # (3)
    poppet_chamber = c.poppet_chamber_compliance_inv * (
        q_c + q_s - q_p - c.poppet_chamber_area * y_dot
    )  # (4) with its swept term
    force_x, force_y = net_forces(real, c, tank_pressure)
    if c.static_friction > 0.0:
        force_x += bearing_friction(x_dot, force_x, c)
    main_valve = (
        stop_acceleration(real[X], x_dot, force_x, c.main_valve_mass, c.main_valve_stroke)
        * c.main_valve_free
    )  # (6)
    poppet = stop_acceleration(
        real[Y], y_dot, force_y, c.pilot_poppet_mass, c.poppet_stroke
    )  # (7)
    return supply, intermediate, pilot, poppet_chamber, x_dot, main_valve, y_dot, poppet


def state_derivative(state, inlet_flow, c, tank_pressure=0.0):
    """d(state)/dt as a new array at inlet_flow [m^3/s] and tank_pressure [Pa, gauge]."""
    return np.array(
        derivatives(np.asarray(state, dtype=float), float(inlet_flow), c, float(tank_pressure))
    )
