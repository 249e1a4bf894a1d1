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
non-finite or absurd state stops it with IntegrationError. A supply pressure
beyond burst_pressure counts as an overpressure only if the step that crossed it
was accurate (one step and two half steps agree): a numerical instability
that happens to cross the limit first is a divergence.

A step whose stiffest chamber would put RK4 beyond its stability
(model.fastest_chamber_rate) is taken as up to MAX_SPLITS equal sub-steps; at
the paper's operating points that never happens.

rk4_lanes advances several independent valves (lanes: parameter sets and
states) through the same inlet-flow schedule at once, stage by stage across
the lanes, calling the same model.derivatives per lane in the same order of
operations: its results are bit-identical to rk4_steps, but the processor
overlaps the lanes' independent arithmetic, which makes a study's runs faster.
"""

import numpy as np
from valve_sim.core.errors import IntegrationError, OverpressureError
from valve_sim.core.jit import jit
from valve_sim.core.limits import (
    describe_state,
    NUMERICAL_CEILING,
    state_check,
    STATE_OK,
    STATE_OVERPRESSURE,
    state_problem,
)
from valve_sim.core.model import (
    Coefficients,
    derivatives,
    fastest_chamber_rate,
    P_S,
    X,
    X_DOT,
    Y,
    Y_DOT,
)


# Largest step * chamber rate taken in one RK4 step; RK4's stability limit on a real
# eigenvalue is 2.785, and the margin covers the coupling the diagonal rate leaves out.
STEP_RATE_LIMIT = 2.0
# At most this many sub-steps per step: enough for a chamber made stiff by the operating
# point at the paper's 10 us, not a licence for steps far beyond what the model allows.
MAX_SPLITS = 8
# An accurate step: its supply pressure agrees with two half steps' within this share of p_burst.
CROSSING_TOLERANCE = 1e-3
# The question is asked every this many steps (0.1 ms at 10 us) and its answer kept in
# between: a chamber's rate changes with the flows and openings, over milliseconds, and
# STEP_RATE_LIMIT keeps 28 % below RK4's limit; asking every step cost a third of the run.
CHECK_EVERY = 10


@jit
def rest_on_stops(state, position, velocity, stroke):
    """Inelastic contact: a body that passed its seat (0) or end stop (stroke) rests on it."""
    if state[position] <= 0.0:
        state[position] = 0.0
        state[velocity] = max(state[velocity], 0.0)
    elif state[position] >= stroke:
        state[position] = stroke
        state[velocity] = min(state[velocity], 0.0)


@jit
def enforce_stops(state, c):
    """
    Keep the valves between their seats and end stops, p_s at most the supply's limit.

    The supply's relief (supply_pressure_limit, model.derivatives) is a stop for p_s:
    a step that overshoots it ends on it.
    """
    rest_on_stops(state, X, X_DOT, c.main_valve_stroke)
    rest_on_stops(state, Y, Y_DOT, c.poppet_stroke)
    if state[P_S] > c.supply_pressure_limit:
        state[P_S] = c.supply_pressure_limit


@jit
def splits_needed(state, c, step):
    """Return the number of equal sub-steps that keep RK4 stable on the stiffest chamber."""
    return min(int(step * fastest_chamber_rate(state, c) / STEP_RATE_LIMIT) + 1, MAX_SPLITS)


@jit
def rk4_step(state, q, c, h, k1, k2, k3, k4, stage):
    """One classical RK4 step of size h [s] at inlet flow q, then the seats and stops."""
    n = state.shape[0]
    derivatives(state, q, c, k1)
    for i in range(n):
        stage[i] = state[i] + 0.5 * h * k1[i]
    derivatives(stage, q, c, k2)
    for i in range(n):
        stage[i] = state[i] + 0.5 * h * k2[i]
    derivatives(stage, q, c, k3)
    for i in range(n):
        stage[i] = state[i] + h * k3[i]
    derivatives(stage, q, c, k4)
    for i in range(n):
        state[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    enforce_stops(state, c)


@jit
def rk4_steps(state, inlet_flows, c, step, record_every, record):
    """
    Advance state in place by len(inlet_flows) RK4 steps of size step [s].

    inlet_flows[k] [m^3/s] is held during step k; a step is split where
    splits_needed() asks for it (asked every CHECK_EVERY steps). Every
    record_every steps the state is copied into the next row of record. Returns
    (steps completed, limits verdict): fewer than len(inlet_flows) steps means the
    state left the limits (verdict STATE_OVERPRESSURE or STATE_DIVERGED; state
    holds those values).
    """
    n = state.shape[0]
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    stage = np.empty(n)
    row = 0
    until_record = record_every
    splits = 1
    for k in range(inlet_flows.shape[0]):
        q = inlet_flows[k]
        if k % CHECK_EVERY == 0:
            splits = splits_needed(state, c, step)
        h = step / splits
        for _ in range(splits):
            rk4_step(state, q, c, h, k1, k2, k3, k4, stage)
        verdict = state_check(state, c.burst_pressure)
        if verdict != STATE_OK:
            return k, verdict
        until_record -= 1
        if until_record == 0:
            until_record = record_every
            if row < record.shape[0]:
                record[row, :] = state
                row += 1
    return inlet_flows.shape[0], STATE_OK


def crossing_is_accurate(start, inlet_flows, done, c, step):
    """
    Check that step done from start (the first to cross burst_pressure) was accurate.

    Repeats the steps before it, then compares that step with two half steps,
    with the limit lifted: a physical pressure rise is resolved by the step and
    both agree; an instability is not.
    """
    unlimited = c._replace(burst_pressure=NUMERICAL_CEILING)
    before = start.copy()
    rk4_steps(before, inlet_flows[:done], unlimited, step, 1, np.empty((0, 8)))
    q = inlet_flows[slice(done, done + 1)]
    full, halves = before.copy(), before.copy()
    rk4_steps(full, q, unlimited, step, 1, np.empty((0, 8)))
    rk4_steps(halves, np.repeat(q, 2), unlimited, 0.5 * step, 1, np.empty((0, 8)))
    gap = abs(full[P_S] - halves[P_S])  # the supply: the pressure the limit is about
    return bool(gap <= CROSSING_TOLERANCE * c.burst_pressure)


def _failure(start, reached, inlet_flows, done, c, step, time, verdict):
    """
    Return the error of a run that left the limits at step done (0-based) of this call.

    start: the state at the start of the call; reached: the state the failing step
    produced; verdict: state_check's. OverpressureError if the step that crossed
    burst_pressure was accurate, else IntegrationError; steps_done set.
    """
    where = (
        f'at t = {time + (done + 1) * step:.6f} s (step {done + 1} of this call, '
        f'step size {step:g} s, inlet flow {inlet_flows[done]:g} m^3/s)'
    )
    if verdict == STATE_OVERPRESSURE and crossing_is_accurate(
        start, inlet_flows, done, c, float(step)
    ):
        error = OverpressureError(
            f'{state_problem(reached, c.burst_pressure)} {where}; '
            'the last state within the limits is kept.'
        )
    else:
        error = IntegrationError(
            f'integration diverged {where}: {describe_state(reached)}. '
            'Reduce the step size or check the parameters.'
        )
    error.steps_done = done
    return error


def advance(state, inlet_flows, coefficients, step, record_every=0, time=0.0):
    """
    Advance state (modified in place) through inlet_flows, one RK4 step each.

    state: float64 array of 8; inlet_flows: array of q_in [m^3/s] per step;
    step: step size [s]; record_every: record the state every so many steps (0: no record);
    time: model time at the start [s], only used for error messages.
    Returns the recorded states (rows). When a state leaves the limits raises
    OverpressureError (beyond burst_pressure) or IntegrationError (diverged) and
    leaves state as it was before the call.
    """
    inlet_flows = np.ascontiguousarray(inlet_flows, dtype=float)
    rows = len(inlet_flows) // record_every if record_every else 0
    record = np.empty((rows, 8))
    start = state.copy()
    done, verdict = rk4_steps(
        state, inlet_flows, coefficients, float(step), max(record_every, 1), record
    )
    if done < len(inlet_flows):
        error = _failure(start, state.copy(), inlet_flows, done, coefficients, step, time, verdict)
        state[:] = start
        raise error
    return record


def _lane_coefficients_function():
    """
    Compile lane_coefficients(table, lane) -> Coefficients of column lane of table.

    Generated from Coefficients' fields so that it follows any field added to the
    model; a namedtuple cannot be built from an array column any other way in numba.
    """
    arguments = ', '.join(f'table[{i}, lane]' for i in range(len(Coefficients._fields)))
    namespace = {'Coefficients': Coefficients}
    exec(f'def lane_coefficients(table, lane):\n    return Coefficients({arguments})\n', namespace)
    return jit(namespace['lane_coefficients'], cache=False)


lane_coefficients = _lane_coefficients_function()


@jit
def rk4_lanes(
    states, inlet_flows, table, step, record_every, records, completed, failures, verdicts
):
    """
    Advance every lane (column) of states [8 x lanes] by len(inlet_flows) RK4 steps.

    The same arithmetic as rk4_steps, lane by lane: a lane whose step must be split
    (splits_needed) takes it alone with rk4_step. table [fields x lanes]: each
    lane's Coefficients as a column. Every record_every steps the states go into
    records[lane, row]. completed[lane] is set to the number of steps the lane
    completed: fewer than len(inlet_flows) means its state left the limits; that
    state goes into failures[:, lane], verdicts[lane] says how (limits.state_check),
    and the lane's later values mean nothing.
    """
    n, lanes = states.shape
    k1 = np.empty((n, lanes))
    k2 = np.empty((n, lanes))
    k3 = np.empty((n, lanes))
    k4 = np.empty((n, lanes))
    stage = np.empty((n, lanes))
    single = np.empty((5, n))
    split = np.zeros(lanes, dtype=np.bool_)
    splits = np.ones(lanes, dtype=np.int64)
    steps = inlet_flows.shape[0]
    for j in range(lanes):
        completed[j] = steps
        verdicts[j] = STATE_OK
    row = 0
    until_record = record_every
    for k in range(steps):
        q = inlet_flows[k]
        for j in range(lanes):
            split[j] = False
            if completed[j] < steps:
                continue
            c = lane_coefficients(table, j)
            if k % CHECK_EVERY == 0:
                splits[j] = splits_needed(states[:, j], c, step)
            if splits[j] > 1:
                split[j] = True
                state = states[:, j].copy()
                for _ in range(splits[j]):
                    rk4_step(
                        state, q, c, step / splits[j], single[0], single[1], single[2],
                        single[3], single[4]
                    )
                states[:, j] = state
                verdicts[j] = state_check(state, c.burst_pressure)
                if verdicts[j] != STATE_OK:
                    completed[j] = k
                    failures[:, j] = state
        for j in range(lanes):
            derivatives(states[:, j], q, lane_coefficients(table, j), k1[:, j])
        for i in range(n):
            for j in range(lanes):
                stage[i, j] = states[i, j] + 0.5 * step * k1[i, j]
        for j in range(lanes):
            derivatives(stage[:, j], q, lane_coefficients(table, j), k2[:, j])
        for i in range(n):
            for j in range(lanes):
                stage[i, j] = states[i, j] + 0.5 * step * k2[i, j]
        for j in range(lanes):
            derivatives(stage[:, j], q, lane_coefficients(table, j), k3[:, j])
        for i in range(n):
            for j in range(lanes):
                stage[i, j] = states[i, j] + step * k3[i, j]
        for j in range(lanes):
            derivatives(stage[:, j], q, lane_coefficients(table, j), k4[:, j])
        # The update of every unsplit lane in one sweep (a split lane took its step above;
        # a frozen lane's values no longer matter).
        for i in range(n):
            for j in range(lanes):
                rate = k1[i, j] + 2.0 * k2[i, j] + 2.0 * k3[i, j] + k4[i, j]
                updated = states[i, j] + step / 6.0 * rate
                states[i, j] = states[i, j] if split[j] else updated
        for j in range(lanes):
            if completed[j] < steps or split[j]:
                continue
            state, c = states[:, j], lane_coefficients(table, j)
            enforce_stops(state, c)
            verdicts[j] = state_check(state, c.burst_pressure)
            if verdicts[j] != STATE_OK:
                completed[j] = k
                failures[:, j] = state
        until_record -= 1
        if until_record == 0:
            until_record = record_every
            if row < records.shape[1]:
                for j in range(lanes):
                    records[j, row, :] = states[:, j]
                row += 1


def advance_lanes(states, inlet_flows, coefficient_sets, step, record_every=0, time=0.0):
    """
    Advance several valves (rows of states, modified in place) through the same inlet_flows.

    states: float64 array [lanes x 8]; coefficient_sets: one Coefficients per lane;
    the other arguments as for advance(). Returns (records [lanes x rows x 8],
    errors): errors[lane] is None or the IntegrationError (or OverpressureError) of
    a lane that left the limits, whose state is then left as it was before the call.
    The lanes do not affect each other, and each gives exactly what advance() gives
    it alone.
    """
    inlet_flows = np.ascontiguousarray(inlet_flows, dtype=float)
    lanes = len(states)
    rows = len(inlet_flows) // record_every if record_every else 0
    records = np.empty((lanes, rows, 8))
    start = np.array(states, dtype=float)
    columns = np.ascontiguousarray(start.T)
    table = np.array([tuple(c) for c in coefficient_sets], dtype=float).T.copy()
    completed = np.empty(lanes, dtype=np.int64)
    failures = np.empty_like(columns)
    verdicts = np.empty(lanes, dtype=np.int64)
    rk4_lanes(
        columns,
        inlet_flows,
        table,
        float(step),
        max(record_every, 1),
        records,
        completed,
        failures,
        verdicts,
    )
    errors = []
    for lane, done in enumerate(completed):
        if done < len(inlet_flows):
            errors.append(
                _failure(
                    start[lane],
                    failures[:, lane].copy(),
                    inlet_flows,
                    done,
                    coefficient_sets[lane],
                    step,
                    time,
                    verdicts[lane],
                )
            )
            states[lane] = start[lane]
        else:
            errors.append(None)
            states[lane] = columns[:, lane]
    return records, errors
