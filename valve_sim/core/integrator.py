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
Fixed-step fourth-order Runge-Kutta integration of the valve model.

The paper integrates Eqs. (1)-(16) with classical RK4 at a fixed 10 us step; so
do we, in one kernel shared by the offline tools and the real-time node. After
each step the valves are kept at their seats and end stops (inelastic contact),
and the state is checked against the physical limits (valve_sim.core.limits):
beyond burst_pressure the integration stops with OverpressureError, a
non-finite or absurd state stops it with IntegrationError. A chamber beyond
burst_pressure (the supply, or an inner chamber such as V_p compressed by the main
valve that a tank step slammed open) counts as an overpressure only if the step
that crossed it was accurate (one step and two half steps agree in every chamber):
a numerical instability that happens to cross the limit first is a divergence.

Each step of the schedule is taken as n equal RK4 sub-steps, n chosen by
splits_needed(): at least what keeps RK4 stable on the stiffest chamber
(model.fastest_chamber_rate), and as many more as make one sub-step agree with two
half sub-steps (step doubling, an estimate of the local error) within
ERROR_TOLERANCE. The choice is made every CHECK_EVERY steps and whenever an input
moved by more than INPUT_CHANGE, and may halve at each choice; in between, the
stability bound alone is asked every step and may only raise it (a fault that
opens the poppet in a few steps makes its chamber stiff between two choices). At the
paper's operating points n is 1. Before, n was capped at 8 and judged by the
stiffness bound alone: a state that needed more (a broken or weakened pilot spring,
a blocked damping orifice) was integrated unstably, and the run settled in a
numerical limit cycle whose own stiffness the bound found acceptable (docs/model.md,
"Step splitting"). A step that needs more than STIFF_SPLITS RK4 sub-steps is taken by
the stiff-stable ROS2 instead (split_step, stiff_step, valve_sim.core.rosenbrock): a
chamber the run drives faster than RK4 can follow at that cost; step_problem() refuses a
valve and step whose bodies ring faster than max_splits() (MAX_SPLITS, or sub-steps of
MIN_SUB_STEP at larger steps) follow.

One RK4 step is rk4_step(), a pure function of the state as an 8-tuple (the
model's derivatives() likewise), so that the compiler keeps a state in registers.
Its two inputs, the inlet flow and the tank pressure, are held over a step; the
kernels take both as arrays with one value per step. rk4_steps takes it for one
valve; valve_sim.core.lanes takes it for many valves at once, bit-identically.

Inside a kernel each chamber is carried as its liquid pressure p* (model.liquid_state: the
pressure itself at and above the vapour pressure, a cavity's volume below it, docs/model.md
"Cavitation"); what leaves it, the records and the state advance() returns, are pressures.

Over 400 lines on purpose: the RK4 step, the choice of its sub-steps and the checks of
a step's end are inlined together into every kernel, and are read side by side.
"""

import numpy as np
from valve_sim.core.errors import IntegrationError, OverpressureError, ParameterError
from valve_sim.core.jit import jit
from valve_sim.core.limits import (
    describe_state,
    highest_chamber,
    NUMERICAL_CEILING,
    state_check,
    STATE_DIVERGED,
    STATE_OK,
    STATE_OVERPRESSURE,
    state_problem,
)
from valve_sim.core.model import (
    derivatives,
    fastest_body_rate,
    fastest_chamber_rate,
    liquid_state,
    P_C,
    P_M,
    P_P,
    P_S,
    pressure_state,
    STATE_NAMES,
    X,
    X_DOT,
    Y,
    Y_DOT,
)
from valve_sim.core.rosenbrock import ros2_step


# Largest step * chamber rate taken in one RK4 step; RK4's stability limit on a real
# eigenvalue is 2.785, and the margin covers the coupling the diagonal rate leaves out.
STEP_RATE_LIMIT = 2.0
# At most this many RK4 sub-steps per step (10 ns at the paper's 10 us): beyond it a chamber
# is faster than RK4 can follow at a cost the real-time node affords: ROS2 takes the step.
MAX_SPLITS = 1024
# ... or as many as make sub-steps of MIN_SUB_STEP [s] (about the paper's 10 us / MAX_SPLITS),
# whichever is more: the physics sets the sub-step a valve needs, so a valve that RK4
# integrates at 10 us is not handed to ROS2 at 100 us (the catalogue's largest step).
MIN_SUB_STEP = 1e-8
# More RK4 sub-steps than this: ROS2 takes the step (stiff_step), which costs about as much
# as 64 RK4 sub-steps where a chamber is that stiff (bench/bench_step_split.py).
STIFF_SPLITS = 64
# The stiff step (stiff_step) halves a sub-step at most this many times (0.6 ps at 10 us):
# its sub-steps adapt, so only the few that resolve a chamber's fastest relaxation are short.
STIFF_HALVINGS = 24
# A sub-step is accurate when it agrees with two half sub-steps within this share of
# burst_pressure (pressures) and of the stroke (positions): 1e-6 is 35 Pa at 35 MPa.
ERROR_TOLERANCE = 1e-6
# An accurate step: its chamber pressures agree with two half steps' within this share of p_burst.
CROSSING_TOLERANCE = 1e-3
# The split is chosen every this many steps (0.1 ms at 10 us) and kept in between, and
# whenever an input moved since the last choice by more than INPUT_CHANGE (flow [m^3/s],
# tank pressure [Pa]): a chamber's rate changes with the flows and openings over
# milliseconds, an input step changes it at once.
CHECK_EVERY = 10
INPUT_CHANGE = (1e-7, 1e4)


@jit
def rest_on_stops(position, velocity, stroke):
    """Inelastic contact: a body that passed its seat (0) or end stop (stroke) rests on it."""
    if position <= 0.0:
        return 0.0, max(velocity, 0.0)
    if position >= stroke:
        return stroke, min(velocity, 0.0)
    return position, velocity


@jit
def on_stops(state, c):
    """
    Return state (an 8-tuple) with the valves between their seats and end stops.

    The supply's relief (supply_pressure_limit, model.derivatives) is a stop for p_s:
    a step that overshoots it ends on it.
    """
    x, x_dot = rest_on_stops(state[X], state[X_DOT], c.main_valve_stroke)
    y, y_dot = rest_on_stops(state[Y], state[Y_DOT], c.poppet_stroke)
    p_s = c.supply_pressure_limit if state[P_S] > c.supply_pressure_limit else state[P_S]
    return p_s, state[P_M], state[P_P], state[P_C], x, x_dot, y, y_dot


@jit
def moved(state, factor, rate):
    """Return state + factor * rate, element by element (8-tuples)."""
    return (
        state[0] + factor * rate[0],
        state[1] + factor * rate[1],
        state[2] + factor * rate[2],
        state[3] + factor * rate[3],
        state[4] + factor * rate[4],
        state[5] + factor * rate[5],
        state[6] + factor * rate[6],
        state[7] + factor * rate[7],
    )


@jit
def rk4_rate(k1, k2, k3, k4):
    """Return RK4's weighted rate k1 + 2 k2 + 2 k3 + k4, element by element (8-tuples)."""
    return (
        k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0],
        k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1],
        k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2],
        k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3],
        k1[4] + 2.0 * k2[4] + 2.0 * k3[4] + k4[4],
        k1[5] + 2.0 * k2[5] + 2.0 * k3[5] + k4[5],
        k1[6] + 2.0 * k2[6] + 2.0 * k3[6] + k4[6],
        k1[7] + 2.0 * k2[7] + 2.0 * k3[7] + k4[7],
    )


@jit
def rk4_step(state, q, p_t, c, h):
    """
    Return the state (an 8-tuple) after one classical RK4 step of size h [s].

    The inputs are held over the step: inlet flow q [m^3/s], tank pressure p_t [Pa, gauge].
    """
    k1 = derivatives(state, q, c, p_t)
    k2 = derivatives(moved(state, 0.5 * h, k1), q, c, p_t)
    k3 = derivatives(moved(state, 0.5 * h, k2), q, c, p_t)
    k4 = derivatives(moved(state, h, k3), q, c, p_t)
    return on_stops(moved(state, h / 6.0, rk4_rate(k1, k2, k3, k4)), c)


@jit
def step_error(whole, halves, c):
    """Return the gap between a sub-step and two half sub-steps in ERROR_TOLERANCE units."""
    pressure_scale = 1.0 / (ERROR_TOLERANCE * c.burst_pressure)
    gap = 0.0
    for i in range(P_S, P_C + 1):
        gap = max(gap, abs(whole[i] - halves[i]) * pressure_scale)
    gap = max(gap, abs(whole[X] - halves[X]) / (ERROR_TOLERANCE * c.main_valve_stroke))
    return max(gap, abs(whole[Y] - halves[Y]) / (ERROR_TOLERANCE * c.poppet_stroke))


@jit
def max_splits(step):
    """Return the most sub-steps a step of size step [s] may take (MAX_SPLITS, MIN_SUB_STEP)."""
    return max(MAX_SPLITS, int(step / MIN_SUB_STEP))


@jit
def stable_splits(state, c, step, tank_pressure=0.0):
    """Return the sub-steps keeping RK4 stable on the fastest chamber or body (<= max_splits+1)."""
    rate = max(
        fastest_chamber_rate(state, c, tank_pressure), fastest_body_rate(state, c, tank_pressure)
    )
    return min(int(step * rate / STEP_RATE_LIMIT) + 1, max_splits(step) + 1)


@jit
def splits_needed(state, c, step, tank_pressure=0.0, inlet_flow=0.0, previous=1):
    """
    Return the number of equal RK4 sub-steps for a step of size step [s] from state.

    At least what keeps RK4 stable on the stiffest chamber, at least half of previous
    (the last choice), and doubled until a sub-step agrees with two half sub-steps
    within ERROR_TOLERANCE (inlet_flow [m^3/s] and tank_pressure [Pa] held). More
    than max_splits(step): that + 1, which split_step takes as a step for ROS2.
    """
    splits = max(stable_splits(state, c, step, tank_pressure), previous // 2)
    limit = max_splits(step)
    while splits <= limit:
        h = step / splits
        # The sub-step, then two half sub-steps, through ONE call of rk4_step: every
        # call site of an inline='always' kernel compiles the model's equations again.
        origin = as_tuple(state)  # a tuple whether state came as one or as an array
        whole = halves = origin
        for stage in range(3):
            start, size = (origin, h) if stage == 0 else (halves, 0.5 * h)
            reached = rk4_step(start, inlet_flow, tank_pressure, c, size)
            if stage == 0:
                whole = reached
            else:
                halves = reached
        if step_error(whole, halves, c) <= 1.0:
            return splits
        splits *= 2
    return limit + 1


@jit
def stiff_step(state, q, p_t, c, step):
    """
    Return (state, True) after one step of size step [s] in ROS2 sub-steps, or (state, False).

    For a step RK4 cannot take in STIFF_SPLITS sub-steps (a chamber relaxing faster
    than nanoseconds, valve_sim.core.rosenbrock). Each sub-step is compared with two
    half sub-steps (step doubling, within ERROR_TOLERANCE as splits_needed) and the
    halves are kept; a sub-step that fails is halved, one that passes with a margin
    doubles the next. A state off its stiff chamber's quasi-static pressure (RK4's
    last sub-steps lag it) takes sub-steps of that chamber's time constant, down to a
    nanosecond, and then grows them again: some 30 sub-steps at 10 us. False (the state
    unchanged) if a sub-step would have to be shorter than step / 2^STIFF_HALVINGS: a
    divergence.
    """
    current = as_tuple(state)
    done, h, shortest = 0.0, step, step * 0.5**STIFF_HALVINGS
    while step - done > 1e-6 * shortest:  # what rounding of the sum leaves is no sub-step
        h = min(h, step - done)
        # The sub-step, then two half sub-steps, through ONE call site of ros2_step.
        whole = halves = current
        for stage in range(3):
            start, size = (current, h) if stage == 0 else (halves, 0.5 * h)
            reached = on_stops(ros2_step(start, q, p_t, c, size), c)
            if stage == 0:
                whole = reached
            else:
                halves = reached
        error = step_error(whole, halves, c)
        if error > 1.0 or error != error:
            if 0.5 * h < shortest * (1.0 - 1e-9):
                return as_tuple(state), False
            h *= 0.5
            continue
        current, done = halves, done + h
        if error < 0.1:
            h *= 2.0
    return current, True


@jit
def split_step(state, q, p_t, c, step, splits):
    """
    Return (state, True) after one step of size step [s], or (state, False) if it diverged.

    splits (splits_needed, stable_splits) equal RK4 sub-steps; more than STIFF_SPLITS for a
    stiff chamber (the bodies' own modes would need fewer), or more than max_splits(step):
    ROS2 sub-steps instead (stiff_step), cheaper there.
    """
    if splits > max_splits(step) or (
        splits > STIFF_SPLITS
        and step * fastest_body_rate(state, c, p_t) < STIFF_SPLITS * STEP_RATE_LIMIT
    ):  # ... but a body ringing that fast stays RK4's: ROS2 would damp its ring away
        return stiff_step(state, q, p_t, c, step)
    h = step / splits
    for _ in range(splits):
        state = rk4_step(state, q, p_t, c, h)
    return state, True


@jit
def choice_due(k, check_every, q, p_t, chosen_q, chosen_p_t):
    """Return whether step k chooses its split: every check_every steps, or an input moved."""
    return (
        k % check_every == 0
        or abs(q - chosen_q) > INPUT_CHANGE[0]
        or abs(p_t - chosen_p_t) > INPUT_CHANGE[1]
    )


@jit
def as_tuple(state):
    """Return the 8-array state as an 8-tuple."""
    return state[0], state[1], state[2], state[3], state[4], state[5], state[6], state[7]


@jit
def rk4_steps(
    state, inlet_flows, tank_pressures, c, step, record_every, record, check_every=CHECK_EVERY
):
    """
    Advance state in place by len(inlet_flows) RK4 steps of size step [s].

    inlet_flows[k] [m^3/s] and tank_pressures[k] [Pa, gauge] are held during step k
    (tank_pressures as long as inlet_flows); a step is split where
    splits_needed() asks for it (asked every check_every steps: CHECK_EVERY, a
    constant of the compiled kernel unless given; 0: never, plain RK4, for
    bench/bench_step_split.py) and when an input moved (choice_due). Every
    record_every steps the state is copied into the next row of record. Returns
    (steps completed, limits verdict): fewer than len(inlet_flows) steps means the
    state left the limits (verdict STATE_OVERPRESSURE or STATE_DIVERGED; state
    holds those values) or failed even in the stiff step's shortest sub-steps
    (STATE_DIVERGED).
    """
    current = liquid_state(as_tuple(state), c)  # each chamber's liquid pressure p*
    row = 0
    until_record = record_every
    splits, chosen_q, chosen_p_t = 1, 0.0, 0.0
    for k in range(inlet_flows.shape[0]):
        q, p_t = inlet_flows[k], tank_pressures[k]
        if check_every <= 0:
            pass  # plain RK4: bench/bench_step_split.py's baseline, never a run's
        elif choice_due(k, check_every, q, p_t, chosen_q, chosen_p_t):
            splits = splits_needed(current, c, step, p_t, q, splits)
            chosen_q, chosen_p_t = q, p_t
        else:
            splits = max(splits, stable_splits(current, c, step, p_t))
        current, accurate = split_step(current, q, p_t, c, step, splits)
        reached = pressure_state(current, c)
        if not accurate:
            state[:] = reached
            return k, STATE_DIVERGED
        verdict = state_check(reached, c.burst_pressure)
        if verdict != STATE_OK:
            state[:] = reached
            return k, verdict
        until_record -= 1
        if until_record == 0:
            until_record = record_every
            if row < record.shape[0]:
                for i in range(8):
                    record[row, i] = reached[i]
                row += 1
    state[:] = pressure_state(current, c)
    return inlet_flows.shape[0], STATE_OK


def step_problem(c, step):
    """
    Return why step [s] cannot integrate the valve of Coefficients c, or None if it can.

    Its bodies' modes (model.fastest_body_rate) do not depend on the state but for the
    flow force, bounded here at p_c - p_t = burst_pressure. If keeping RK4 stable on them
    needs more than max_splits(step), the valve is refused before it starts: the stiff
    step would damp a ringing body out of the answer. Chambers are not judged: one that
    is (or the run makes) too stiff for RK4 takes ROS2's steps (stiff_step).
    """
    bound = np.zeros(8)
    bound[P_C] = c.burst_pressure
    body = fastest_body_rate(bound, c, 0.0)
    needed, limit = int(step * body / STEP_RATE_LIMIT) + 1, max_splits(step)
    if needed <= limit:
        return None
    return (
        f'this valve cannot be integrated at step size {step:g} s: its main valve and pilot '
        f'poppet on their fluid springs ring at up to {body / (2.0 * np.pi):.4g} Hz, which '
        f'needs {needed} sub-steps of RK4 per step, more than the {limit} allowed (sub-steps '
        f'of {step / limit:.3g} s); use heavier bodies, larger chambers or a smaller step'
    )


def crossing_is_accurate(start, inlet_flows, done, c, step, tank_pressures=0.0):
    """
    Check that step done from start (the first to cross burst_pressure) was accurate.

    Repeats the steps before it, then compares that step with two half steps,
    with the limit lifted: a physical pressure rise is resolved by the step and
    both agree; an instability is not. tank_pressures: as for advance().
    """
    inlet_flows, tank_pressures = step_inputs(inlet_flows, tank_pressures)
    unlimited = c._replace(burst_pressure=NUMERICAL_CEILING)
    before = start.copy()
    rk4_steps(
        before, inlet_flows[:done], tank_pressures[:done], unlimited, step, 1, np.empty((0, 8))
    )
    q, p_t = inlet_flows[slice(done, done + 1)], tank_pressures[slice(done, done + 1)]
    full, halves = before.copy(), before.copy()
    rk4_steps(full, q, p_t, unlimited, step, 1, np.empty((0, 8)))
    rk4_steps(
        halves, np.repeat(q, 2), np.repeat(p_t, 2), unlimited, 0.5 * step, 1, np.empty((0, 8))
    )
    gap = np.max(np.abs(full[P_S:P_C + 1] - halves[P_S:P_C + 1]))  # every chamber's
    return bool(gap <= CROSSING_TOLERANCE * c.burst_pressure)


def limits_error(start, reached, inlet_flows, done, c, step, time, verdict, tank_pressures):
    """
    Return the error of a run that left the limits at step done (0-based) of this call.

    start: the state at the start of the call; reached: the state the failing step
    produced; verdict: state_check's. OverpressureError if the step that crossed
    burst_pressure was accurate, else IntegrationError; steps_done set.
    """
    tank = tank_pressures[done]
    where = (
        f'at t = {time + (done + 1) * step:.6f} s (step {done + 1} of this call, '
        f'step size {step:g} s, inlet flow {inlet_flows[done]:g} m^3/s'
        + (f', tank pressure {tank:g} Pa gauge' if tank else '')
        + ')'
    )
    if verdict == STATE_OVERPRESSURE and crossing_is_accurate(
        start, inlet_flows, done, c, float(step), tank_pressures
    ):
        error = OverpressureError(
            f'{state_problem(reached, c.burst_pressure)} {where}; '
            'the last state within the limits is kept.'
        )
        error.chamber = STATE_NAMES[highest_chamber(reached)]
    else:
        error = IntegrationError(
            f'integration diverged {where}: {describe_state(reached)}. '
            'Reduce the step size or check the parameters.'
        )
    error.steps_done = done
    return error


def step_inputs(inlet_flows, tank_pressures):
    """
    Return (inlet flows, tank pressures) as contiguous float arrays of one length.

    tank_pressures: an array with one value per step, or one value for every step.
    """
    inlet_flows = np.ascontiguousarray(inlet_flows, dtype=float)
    if np.ndim(tank_pressures) == 0:
        return inlet_flows, np.full(len(inlet_flows), float(tank_pressures))
    tank_pressures = np.ascontiguousarray(tank_pressures, dtype=float)
    if tank_pressures.shape != inlet_flows.shape:
        raise ParameterError(
            f'{len(tank_pressures)} tank pressures for {len(inlet_flows)} inlet flows'
        )
    return inlet_flows, tank_pressures


def advance(state, inlet_flows, coefficients, step, record_every=0, time=0.0, tank_pressures=0.0):
    """
    Advance state (modified in place) through inlet_flows, one RK4 step each.

    state: float64 array of 8; inlet_flows: array of q_in [m^3/s] per step;
    step: step size [s]; record_every: record the state every so many steps (0: no record);
    time: model time at the start [s], only used for error messages; tank_pressures:
    p_t [Pa, gauge] per step, or one value for all (0: the tank at ambient).
    Returns the recorded states (rows). When a state leaves the limits raises
    OverpressureError (beyond burst_pressure) or IntegrationError (diverged) and
    leaves state as it was before the call.
    """
    inlet_flows, tank_pressures = step_inputs(inlet_flows, tank_pressures)
    rows = len(inlet_flows) // record_every if record_every else 0
    record = np.empty((rows, 8))
    start = state.copy()
    done, verdict = rk4_steps(
        state, inlet_flows, tank_pressures, coefficients, float(step), max(record_every, 1), record
    )
    if done < len(inlet_flows):
        error = limits_error(
            start, state.copy(), inlet_flows, done, coefficients, step, time, verdict,
            tank_pressures,
        )
        state[:] = start
        raise error
    return record
