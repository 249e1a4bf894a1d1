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
Many valves through one RK4 kernel at once: the batch runs of studies.

rk4_lanes takes integrator.rk4_step for LANES independent valves (lanes:
parameter sets and states) through the same input schedules at once, in one
loop over the lanes that the compiler vectorises (SIMD: four lanes per
instruction on AVX2). The same function in the same order of operations: each
lane's result is bit-identical to integrator.rk4_steps (no fast-math),
docs/speed.md. advance_lanes lays the valves out in lanes and reports each one's
result as integrator.advance would.
"""

import math

import numpy as np
from valve_sim.core.integrator import (
    CHECK_EVERY,
    choice_due,
    limits_error,
    rk4_step,
    split_step,
    splits_needed,
    stable_splits,
    step_inputs,
)
from valve_sim.core.jit import jit
from valve_sim.core.limits import state_check, STATE_DIVERGED, STATE_OK
from valve_sim.core.model import Coefficients, HEALTHY_TERMS, liquid_state, pressure_state
from valve_sim.core.model import P_C, P_M, P_P, P_S, X, X_DOT, Y, Y_DOT  # the state's indices


# Valves rk4_lanes advances together: a few vector registers' worth (4 doubles each).
LANES = 16


def _lane_coefficients_function(fixed):
    """
    Compile lane_coefficients(table, lane) -> Coefficients of lane in table [fields x LANES].

    Fields named in fixed take its constant values instead of the table's. Generated
    from Coefficients' fields so that it follows any field added to the model; a
    namedtuple cannot be built from an array column any other way in numba.
    """
    arguments = ', '.join(
        f'FIXED_{name}' if name in fixed else f'table[{i} * LANES + lane]'
        for i, name in enumerate(Coefficients._fields)
    )
    namespace = {'Coefficients': Coefficients, 'LANES': LANES,
                 **{f'FIXED_{name}': value for name, value in fixed.items()}}
    exec(f'def lane_coefficients(table, lane):\n    return Coefficients({arguments})\n', namespace)
    return jit(namespace['lane_coefficients'], cache=False)


lane_coefficients = _lane_coefficients_function({})
# The same for lanes without a fault and above the vapour pressure: the compiler then
# leaves the fault and cavitation terms out (a lane that is below it, or gets there in the
# step, takes its step alone).
healthy_lane_coefficients = _lane_coefficients_function(
    {**HEALTHY_TERMS, 'cavitation_pressure': -math.inf}
)
# The row of the table holding each lane's vapour pressure (gauge).
CAVITATION_ROW = Coefficients._fields.index('cavitation_pressure')


@jit
def below_vapour(state, cavitation_pressure):
    """Return whether a chamber of state is below the vapour pressure (gauge, model.py)."""
    return min(state[P_S], state[P_M], state[P_P], state[P_C]) < cavitation_pressure


@jit
def lane_state(states, lane):
    """Return the state of lane in states [8 x LANES, flat] as an 8-tuple."""
    return (
        states[P_S * LANES + lane],
        states[P_M * LANES + lane],
        states[P_P * LANES + lane],
        states[P_C * LANES + lane],
        states[X * LANES + lane],
        states[X_DOT * LANES + lane],
        states[Y * LANES + lane],
        states[Y_DOT * LANES + lane],
    )


@jit
def set_lane_state(states, lane, state):
    """Write the 8-tuple state of lane into states [8 x LANES, flat]."""
    for i in range(8):
        states[i * LANES + lane] = state[i]


@jit
def rk4_lanes(
    states, inlet_flows, tank_pressures, table, faulty, step, record_every, records, completed,
    verdicts,
):
    """
    Advance LANES valves by len(inlet_flows) RK4 steps together, the same inputs for all.

    states [8 x LANES] and table [fields x LANES] (each lane's Coefficients) are flat
    arrays in rows: a state or coefficient of every lane side by side, so that the
    loop over lanes reads and writes contiguous memory at offsets the compiler
    knows, and vectorises. Each lane takes rk4_step exactly as rk4_steps does. The
    vectorised loop leaves the fault and cavitation terms out; a lane with a fault
    (faulty[lane]: a fault term differs from model.HEALTHY_TERMS), whose step must be
    split (splits_needed) or that starts or ends the step below the vapour pressure
    takes its step alone after it. Every record_every steps the
    states go into records[lane, row]. completed[lane] is set to the number of
    steps the lane completed: fewer than len(inlet_flows) means its state left the
    limits; the lane then stops with that state in states, and verdicts[lane] says
    how (limits.state_check).
    """
    steps = inlet_flows.shape[0]
    splits = np.ones(LANES, dtype=np.int64)
    alone = np.zeros(LANES, dtype=np.bool_)  # stepped after the vectorised loop, or stopped
    checked = np.empty(LANES, dtype=np.int64)
    for j in range(LANES):
        completed[j] = steps
        verdicts[j] = STATE_OK
        # Each chamber as its liquid pressure p* (model.liquid_state) while stepping.
        set_lane_state(states, j, liquid_state(lane_state(states, j), lane_coefficients(table, j)))
    row = 0
    until_record = record_every
    chosen_q, chosen_p_t = 0.0, 0.0
    for k in range(steps):
        q, p_t = inlet_flows[k], tank_pressures[k]
        if choice_due(k, CHECK_EVERY, q, p_t, chosen_q, chosen_p_t):
            chosen_q, chosen_p_t = q, p_t
            for j in range(LANES):
                if completed[j] == steps:
                    state, c = lane_state(states, j), lane_coefficients(table, j)
                    splits[j] = splits_needed(state, c, step, p_t, q, splits[j])
                    alone[j] = (
                        faulty[j] or splits[j] > 1 or below_vapour(state, c.cavitation_pressure)
                    )
        else:
            for j in range(LANES):
                if completed[j] == steps:
                    state, c = lane_state(states, j), lane_coefficients(table, j)
                    splits[j] = max(splits[j], stable_splits(state, c, step, p_t))
                    alone[j] = (
                        faulty[j] or splits[j] > 1 or below_vapour(state, c.cavitation_pressure)
                    )
        # One step of every healthy lane at once: pure arithmetic over contiguous rows.
        for j in range(LANES):
            c = healthy_lane_coefficients(table, j)
            state = lane_state(states, j)
            stepped = rk4_step(state, q, p_t, c, step)
            alone[j] = alone[j] or below_vapour(stepped, table[CAVITATION_ROW * LANES + j])
            set_lane_state(states, j, state if alone[j] else stepped)
            checked[j] = state_check(stepped, c.burst_pressure)
        for j in range(LANES):
            if completed[j] < steps:
                continue
            if alone[j]:
                c = lane_coefficients(table, j)
                state, accurate = split_step(lane_state(states, j), q, p_t, c, step, splits[j])
                set_lane_state(states, j, state)
                checked[j] = (
                    state_check(pressure_state(state, c), c.burst_pressure) if accurate
                    else STATE_DIVERGED
                )
            if checked[j] != STATE_OK:
                completed[j] = k
                verdicts[j] = checked[j]
                alone[j] = True
        until_record -= 1
        if until_record == 0:
            until_record = record_every
            if row < records.shape[1]:
                for j in range(LANES):
                    reached = pressure_state(lane_state(states, j), lane_coefficients(table, j))
                    for i in range(8):
                        records[j, row, i] = reached[i]
                row += 1
    for j in range(LANES):  # back to each chamber's pressure
        state, c = lane_state(states, j), lane_coefficients(table, j)
        set_lane_state(states, j, pressure_state(state, c))


def advance_lanes(
    states, inlet_flows, coefficient_sets, step, record_every=0, time=0.0, tank_pressures=0.0
):
    """
    Advance several valves (rows of states, modified in place) through the same inlet_flows.

    states: float64 array [valves x 8]; coefficient_sets: one Coefficients per valve;
    the other arguments as for advance(). The valves run LANES at a time through
    rk4_lanes (the last group filled up with copies of its first valve). Returns
    (records [valves x rows x 8], errors): errors[valve] is None or the
    IntegrationError (or OverpressureError) of a valve that left the limits, whose
    state is then left as it was before the call. The valves do not affect each
    other, and each gives exactly what advance() gives it alone.
    """
    inlet_flows, tank_pressures = step_inputs(inlet_flows, tank_pressures)
    count = len(states)
    rows = len(inlet_flows) // record_every if record_every else 0
    records = np.empty((count, rows, 8))
    start = np.array(states, dtype=float).reshape((count, 8))
    table = np.array([tuple(c) for c in coefficient_sets], dtype=float)
    faulty = np.array(
        [
            any(getattr(c, name) != value for name, value in HEALTHY_TERMS.items())
            for c in coefficient_sets
        ]
    )
    errors = []
    for first in range(0, count, LANES):
        group = list(range(first, min(first + LANES, count)))
        lanes = group + [first] * (LANES - len(group))
        columns = np.ascontiguousarray(start[lanes].T).reshape(-1)
        completed = np.empty(LANES, dtype=np.int64)
        verdicts = np.empty(LANES, dtype=np.int64)
        lane_records = np.empty((LANES, rows, 8))
        rk4_lanes(
            columns,
            inlet_flows,
            tank_pressures,
            np.ascontiguousarray(table[lanes].T).reshape(-1),
            faulty[lanes],
            float(step),
            max(record_every, 1),
            lane_records,
            completed,
            verdicts,
        )
        ends = columns.reshape((8, LANES)).T
        records[group] = lane_records[: len(group)]
        for lane, valve in enumerate(group):
            if completed[lane] < len(inlet_flows):
                errors.append(
                    limits_error(
                        start[valve],
                        ends[lane].copy(),
                        inlet_flows,
                        completed[lane],
                        coefficient_sets[valve],
                        step,
                        time,
                        verdicts[lane],
                        tank_pressures,
                    )
                )
                states[valve] = start[valve]
            else:
                errors.append(None)
                states[valve] = ends[lane]
    return records, errors
