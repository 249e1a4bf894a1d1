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
Offline runs of the valve model: an inlet-flow step in, sampled waveforms out.

A FlowStep (valve_sim.core.flow_step) is the paper's test: the valve at the exact steady state of
initial_flow, the inlet flow changed to final_flow at step_time (at once, or over
ramp_time), and the run ended at end_time. initial_flow = 0 starts from the
empty, closed valve. The tank's pressure, the second input, is a TankPressure profile
(held, stepped or ramped; the tank at ambient by default), and relief_flows() gives what
the valve passed to the tank at each sample. Faults (a FaultSet) hold from the start; a
fault schedule (valve_sim.core.fault_schedule) changes them at the ticks valve_node would.

simulate() integrates the whole run; run_flows() any inlet-flow schedule. The batch
runs of studies (many parameter sets through one flow step) are valve_sim.core.batch's.

Over 400 lines on purpose: every offline run (simulate, simulate_recorded_flow, the
characteristic's ramp) goes through run_flows and the helpers here that it shares.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import OverpressureError, ParameterError
from valve_sim.core.fault_schedule import FaultEvent, tick_index
from valve_sim.core.faults import FAULT_NAMES, FaultSet, HEALTHY
from valve_sim.core.flow_step import (  # noqa: F401 (also offered here)
    FlowStep,
    LITRE_PER_MINUTE,
    TankPressure,
)
from valve_sim.core.integrator import advance, step_inputs
from valve_sim.core.invariants import run_alarms
from valve_sim.core.jit import jit
from valve_sim.core.limits import schedule_problem, tank_pressure_problem
from valve_sim.core.model import (
    flows as model_flows,
    P_S,
    relief_flows as model_relief_flows,
    STATE_NAMES,
    X_DOT,
)
from valve_sim.core.parameters import validate
from valve_sim.core.steady_state import steady_state
from valve_sim.core.step_check import check_integrable


@dataclass
class Waveforms:
    """
    Sampled run: time [s], states (rows of the 8 model states, SI), and the inputs.

    inlet_flow [m^3/s] and tank_pressure [Pa, gauge] are the inputs applied over the
    interval that ends at each sample (tank_pressure None: the tank at ambient).
    halted: (time [s], reason) of an overpressure the run halted at (run_flows'
    halt_on_overpressure), else None.
    """

    time: np.ndarray
    states: np.ndarray
    inlet_flow: np.ndarray
    # [(time [s], {name: value})] applied
    events: list[tuple[float, dict[str, float]]] = field(default_factory=list)
    halted: tuple[float, str] | None = None
    tank_pressure: np.ndarray | None = None

    def __getitem__(self, name: str) -> np.ndarray:
        return self.states[:, STATE_NAMES.index(name)]

    @property
    def status(self) -> int:
        """0: the run reached its end; 1: it halted at an overpressure (as scipy's OdeResult)."""
        return 0 if self.halted is None else 1

    @property
    def message(self) -> str:
        """Say what status means, in one line."""
        return f'halted at {self.halted[0]:g} s: {self.halted[1]}' if self.halted else (
            'the run reached its end')


def apply_faults(state, faults, changes):
    """
    Return the FaultSet after the fault parameters in changes; state updated in place.

    A main valve that becomes stuck stops where it is: its velocity becomes zero.
    """
    new = faults.changed({n: v for n, v in changes.items() if n in FAULT_NAMES})
    if new.main_valve_stuck and not faults.main_valve_stuck:
        state[X_DOT] = 0.0
    return new


def _event_steps(schedule, steps, step_size, record_every, tick_interval):
    """[(step index, changes)] of the schedule's events, at their ticks, within the run."""
    tick_steps = int(round(tick_interval / step_size))
    if schedule and (
        tick_steps < 1
        or abs(tick_steps * step_size - tick_interval) > 1e-9 * tick_interval
        or tick_steps % record_every
    ):
        raise ParameterError(
            f'a fault schedule needs the tick interval ({tick_interval:g} s) to be a whole '
            f'multiple of the step size ({step_size:g} s) and of the record interval'
        )
    tick_ns = int(round(tick_interval * 1e9))
    grouped = {}
    for event in schedule:
        k = tick_index(event.time_ns, tick_ns) * tick_steps
        if k <= steps:
            grouped.setdefault(k, {}).update(event.changes)
    return sorted(grouped.items())


def main_stage_flow(params, states):
    """Flow through the main stage q_m2 [m^3/s] (Eq. 11) for each row of states."""
    c = coefficients(params)
    return np.array([model_flows(state, c)[1] for state in np.asarray(states, dtype=float)])


RELIEF_COLUMNS = ('relief_flow', 'main_stage_flow', 'pilot_flow', 'seat_leakage_flow')


@jit
def _relief_rows(states, tank_pressures, c, rows, out):
    """Write the relief flow and its parts (RELIEF_COLUMNS) of the rows of states into out."""
    for i in rows:
        main, pilot, leakage = model_relief_flows(states[i], c, tank_pressures[i])
        out[i, 0] = main + pilot + leakage
        out[i, 1] = main
        out[i, 2] = pilot
        out[i, 3] = leakage


def relief_flows(params, waveforms, faults=HEALTHY):
    """
    Flows into the tank [m^3/s] at each sample of waveforms, columns RELIEF_COLUMNS.

    The relief flow (all the valve passes to the tank) and its parts: main stage q_m2,
    pilot stage q_p, seat leakage q_l, at each sample's state and tank pressure, with
    faults (the run's FaultSet from the start) changed by the waveforms' events from
    their times on, as the run applied them.
    """
    states = np.ascontiguousarray(waveforms.states, dtype=float)
    tank = waveforms.tank_pressure
    tank = np.zeros(len(states)) if tank is None else np.ascontiguousarray(tank, dtype=float)
    out = np.empty((len(states), len(RELIEF_COLUMNS)))
    start = 0
    for applied_at, changes in [*waveforms.events, (np.inf, {})]:
        stop = int(np.searchsorted(waveforms.time, applied_at - 1e-12))
        if stop > start:
            rows = np.arange(start, stop)
            _relief_rows(states, tank, coefficients(params, faults), rows, out)
        faults = faults.changed({n: v for n, v in changes.items() if n in FAULT_NAMES})
        start = max(start, stop)
    return out


def step_flows(flow_step, step_size):
    """
    Inlet flow [m^3/s] held during each RK4 step of a run.

    Each step holds the flow at its midpoint: exact for a step on the grid,
    second order for a ramp.
    """
    steps = int(round(flow_step.end_time / step_size))
    return flow_step.inlet_flow((np.arange(steps) + 0.5) * step_size)


def step_tank_pressures(tank, steps, step_size):
    """
    Tank pressure [Pa, gauge] of a TankPressure held during each of steps RK4 steps.

    Midpoints, as step_flows; one number where the tank's pressure is held throughout.
    """
    if tank.final is None or tank.final == tank.initial:
        return float(tank.initial)
    return tank.at((np.arange(steps) + 0.5) * step_size)


def recorded_waveforms(
    initial, record, flows, record_every, step_size, initial_flow, held=0, events=(),
    tanks=None,
):
    """
    Waveforms of a run: the initial state, held rows of it, then the recorded rows.

    tanks: the tank pressure per step [Pa, gauge], the initial one first (None: at ambient).
    """
    rows = held + len(record)
    states = np.empty((rows + 1, len(initial)))
    states[: held + 1] = initial
    states[held + 1:] = record
    sample_steps = np.arange(1, rows + 1) * record_every
    return Waveforms(
        time=np.concatenate([[0.0], sample_steps * step_size]),
        states=states,
        inlet_flow=np.concatenate([[initial_flow], flows[sample_steps - 1]]),
        events=list(events),
        tank_pressure=None if tanks is None else np.concatenate(
            [tanks[:1], tanks[1:][sample_steps - 1]]
        ),
    )


def check_schedule(params, flows, tank_pressures=()):
    """
    Raise ParameterError if an input of the schedules is not valid.

    flows [m^3/s]: inlet flows; tank_pressures [Pa, gauge]: tank pressures.
    """
    problem = schedule_problem(flows, params['max_inlet_flow'])
    if problem:
        raise ParameterError(f'inlet flow schedule: {problem}')
    extremes = (np.min(tank_pressures), np.max(tank_pressures)) if len(tank_pressures) else ()
    for pressure in extremes:
        problem = tank_pressure_problem(float(pressure), params['burst_pressure'])
        if problem:
            raise ParameterError(f'tank pressure schedule: {problem}')


def ramp_flows(max_flow, ramp_time, hold_time, step_size):
    """
    Inlet flow [m^3/s] per RK4 step of a static-characteristic test.

    0 -> max_flow linearly over ramp_time [s], held for hold_time [s], back to 0
    over ramp_time (midpoint flows, as step_flows).
    """
    ramp = int(round(ramp_time / step_size))
    up = (np.arange(ramp) + 0.5) / ramp * max_flow
    return np.concatenate([up, np.full(int(round(hold_time / step_size)), max_flow), up[::-1]])


def run_flows(
    params,
    flows,
    step_size=1e-5,
    record_interval=1e-4,
    initial_flow=0.0,
    faults=HEALTHY,
    schedule=(),
    tick_interval=1e-3,
    halt_on_overpressure=False,
    tank_pressures=0.0,
    initial_tank_pressure=None,
):
    """
    Integrate through a schedule: flows[k] [m^3/s] held during step k, from the steady state.

    tank_pressures: the tank pressure [Pa, gauge] held during each step (an array as
    long as flows), or one for all (0: the tank at ambient). The run starts at the
    exact steady state of initial_flow [m^3/s] (0: the empty, closed valve) and
    initial_tank_pressure [Pa, gauge] (None: the first step's) with faults (a
    FaultSet). schedule: FaultEvents, each applied at the
    first tick (every tick_interval [s], valve_node's publish period) at or after its
    time. Returns Waveforms sampled every record_interval [s]; their events list what
    was applied when (sensor settings included, for the sensor stage). Raises
    IntegrationError if the run diverges, SteadyStateError if the start fails,
    ParameterError for a bad fault or tick interval. halt_on_overpressure: an
    overpressure (OverpressureError) halts the run as it halts valve_node instead: the
    last good state is held to the end, its supply pressure reported at burst_pressure
    (what valve_node publishes), and Waveforms.halted says when and why.
    """
    params = validate(params)  # a dict or a valve.Parameters; ParameterError if invalid
    record_every = max(1, int(round(record_interval / step_size)))
    flows, tanks = step_inputs(flows, tank_pressures)
    if initial_tank_pressure is None:
        initial_tank_pressure = float(tanks[0]) if len(tanks) else float(tank_pressures)
    state = steady_state(params, initial_flow, faults, initial_tank_pressure, stable=False)
    check_integrable(params, step_size, faults)
    check_schedule(params, flows, tanks)
    initial = state.copy()
    records, events, start, halted = [], [], 0, None
    events_at = _event_steps(schedule, len(flows), step_size, record_every, tick_interval)

    def run(stop):
        """Advance from step start to stop; after an overpressure hold to the end."""
        nonlocal halted
        chunk, tank = flows[start:stop], tanks[start:stop]
        c = coefficients(params, faults)
        try:
            return advance(state, chunk, c, step_size, record_every, start * step_size, tank)
        except OverpressureError as error:
            if not halt_on_overpressure:
                raise
            done = error.steps_done  # the steps before the failing one, from the last good state
            whole = done // record_every * record_every
            good = advance(
                state, chunk[:whole], c, step_size, record_every, start * step_size, tank[:whole]
            )
            advance(
                state, chunk[whole:done], c, step_size, 0, (start + whole) * step_size,
                tank[whole:done],
            )
            held = state.copy()
            held[P_S] = params['burst_pressure']
            rows = (len(flows) - start) // record_every - len(good)
            halted = ((start + done + 1) * step_size, str(error))
            return np.vstack([good, np.tile(held, (rows, 1))])

    for stop, changes in events_at:
        records.append(run(stop))
        if halted:
            break
        faults = apply_faults(state, faults, changes)
        if stop == 0:
            initial = state.copy()
        elif len(records[-1]):
            records[-1][-1] = state  # the tick's sample shows the state after the event
        events.append((stop * step_size, changes))
        start = stop
    if not halted:
        records.append(run(len(flows)))
    waveforms = recorded_waveforms(
        initial, np.vstack(records), flows, record_every, step_size, initial_flow, events=events,
        tanks=np.concatenate([[initial_tank_pressure], tanks]),
    )
    waveforms.halted = halted
    return waveforms


def simulate(
    params: Mapping[str, float],
    flow_step: FlowStep = FlowStep(),
    step_size: float = 1e-5,
    record_interval: float = 1e-4,
    faults: FaultSet = HEALTHY,
    schedule: Sequence[FaultEvent] = (),
    tick_interval: float = 1e-3,
    halt_on_overpressure: bool = False,
    tank: TankPressure = TankPressure(),
) -> Waveforms:
    """
    Run a flow step with fixed-step RK4; returns Waveforms sampled every record_interval [s].

    tank: the tank's pressure, a TankPressure (default: at ambient); the run starts
    at the steady state of its initial value. faults, schedule, tick_interval,
    halt_on_overpressure: as run_flows. Raises IntegrationError if the run diverges,
    SteadyStateError if the start fails.
    """
    flows = step_flows(flow_step, step_size)
    return run_flows(
        params,
        flows,
        step_size,
        record_interval,
        flow_step.initial_flow,
        faults,
        schedule,
        tick_interval,
        halt_on_overpressure,
        step_tank_pressures(tank, len(flows), step_size),
        tank.initial,
    )


def simulate_recorded_flow(params, time, inlet_flow, step_size=1e-5, step_times=()):
    """
    Run the model driven by a sampled inlet flow; returns the 8 states at the sample times.

    time [s]: increasing sample times; inlet_flow [m^3/s]: inlet_flow[i] is the flow
    over the interval (time[i-1], time[i]] that ends at sample i (valve_node's
    applied_inlet_flow; a flow meter averaging over its sample interval). The run
    starts at the exact steady state of inlet_flow[0] at time[0]. Sample intervals
    are rounded to whole steps (an error below step_size / 2 per sample, not
    accumulated). step_times [s, on the time axis]: steps known to lie inside an
    interval (located between coarse flow samples): there the flow is inlet_flow[i-1]
    up to the step time and inlet_flow[i] after it, the RK4 step that holds it taking
    the time-weighted mean (so the states move smoothly with a step time). Raises
    IntegrationError or SteadyStateError.
    """
    time = np.asarray(time, dtype=float)
    inlet_flow = np.asarray(inlet_flow, dtype=float)
    ends = np.rint((time - time[0]) / step_size).astype(np.int64)
    counts = np.diff(ends)
    if len(time) < 2 or np.any(counts < 1):
        raise ParameterError('sample times must increase by at least one step size')
    flows = np.repeat(inlet_flow[1:], counts)
    for t_step in step_times:
        i = int(np.searchsorted(time, t_step))  # the interval (time[i-1], time[i]] holding it
        if not 0 < i < len(time):
            continue
        position = (t_step - time[0]) / step_size
        k = min(max(int(position), ends[i - 1]), ends[i] - 1)  # the RK4 step holding it
        before, after = inlet_flow[i - 1], inlet_flow[i]
        flows[ends[i - 1]:k] = before
        share = min(max(position - k, 0.0), 1.0)  # of step k still at the old flow
        flows[k] = share * before + (1.0 - share) * after
    waveforms = run_flows(params, flows, step_size, step_size, float(inlet_flow[0]))
    return waveforms.states[ends]


def simulate_alarms(params, waveforms, faults=HEALTHY):
    """
    Return the invariant Alarms of a run (valve_sim.core.invariants), [] for a sound one.

    faults: the FaultSet the run started with; the run's events change it as they did.
    """
    segments = [(float(waveforms.time[0]), coefficients(params, faults))]
    for time, changes in waveforms.events:
        faults = faults.changed({n: v for n, v in changes.items() if n in FAULT_NAMES})
        segments.append((time, coefficients(params, faults)))
    return run_alarms(
        waveforms.time, waveforms.states, waveforms.inlet_flow, waveforms.tank_pressure, segments
    )
