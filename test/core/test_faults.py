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

"""Valve faults on the paper's step: each fault's physical signature, offline."""

from collections import Counter
from dataclasses import dataclass, fields
import json

import numpy as np
import pytest
from valve_sim.analysis.steps.measures import step_measures
from valve_sim.core.coefficients import coefficients
from valve_sim.core.errors import OverpressureError, ParameterError
from valve_sim.core.fault_schedule import FaultEvent, parse_schedule
from valve_sim.core.faults import FAULT_NAMES, FaultSet, HEALTHY
from valve_sim.core.integrator import advance
from valve_sim.core.model import (
    net_forces,
    P_S,
    seat_leakage_flow,
    state_derivative,
    X,
    X_DOT,
)
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import FlowStep, LITRE_PER_MINUTE, simulate
from valve_sim.core.steady_state import cracking_pressure, steady_state
from valve_sim.recording.bag import BagReader


L = LITRE_PER_MINUTE
PAPER_STEP = FlowStep()


@pytest.fixture(scope='module')
def params():
    return load_parameters().params


@pytest.fixture(scope='module')
def healthy(params):
    return simulate(params)


def measures(waveforms, scenario=PAPER_STEP):
    return step_measures(
        waveforms.time,
        waveforms['supply_pressure'],
        waveforms['main_valve_displacement'],
        scenario.step_time,
        1,
    )


ALL_FAULTS = FaultSet(
    bearing_coulomb_friction=5.0,
    bearing_static_friction=8.0,
    damping_orifice_blockage=0.1,
    bearing_orifice_blockage=0.05,
    pilot_spring_weakening=0.05,
    seat_leakage_diameter=0.2e-3,
    pilot_spring_broken=True,
    main_valve_stuck=True,
)


def test_every_fault_off_is_exactly_the_healthy_model(params, healthy):
    off = ALL_FAULTS.changed({name: type(value)(0) for name, value in ALL_FAULTS.active().items()})
    assert off == HEALTHY and coefficients(params, off) == coefficients(params)
    rng = np.random.default_rng(1)
    for state in steady_state(params, 5 * L) * (1.0 + 0.1 * rng.standard_normal((20, 8))):
        assert np.array_equal(
            state_derivative(state, 2e-4, coefficients(params, off)),
            state_derivative(state, 2e-4, coefficients(params)),
        )
    # Every fault on and off again at the same tick, and explicitly off later: bit for bit.
    on = ALL_FAULTS.as_parameters()
    schedule = [
        FaultEvent(100_000_000, on),
        FaultEvent(100_000_000, off.as_parameters()),
        FaultEvent(300_000_000, off.as_parameters()),
    ]
    scheduled = simulate(params, schedule=schedule)
    assert np.array_equal(scheduled.states, healthy.states)
    assert [t for t, _ in scheduled.events] == pytest.approx([0.1, 0.3])


def test_a_blocked_damping_orifice_raises_p1_and_t1_as_a_smaller_orifice_does(params, healthy):
    blocked = measures(simulate(params, faults=FaultSet(damping_orifice_blockage=0.2))).values
    smaller = dict(params, damping_orifice_diameter=params['damping_orifice_diameter'] * 0.8**0.5)
    same_area = measures(simulate(smaller)).values
    reference = measures(healthy).values
    assert blocked['P_1_percent'] > 1.1 * reference['P_1_percent']
    assert blocked['T_1_ms'] > 1.1 * reference['T_1_ms']
    for name in ('P_1_percent', 'T_1_ms', 'r_d', 'T_d_ms'):
        assert blocked[name] == pytest.approx(same_area[name], rel=1e-6)


@dataclass(frozen=True)
class Triangle(FlowStep):
    """Flow ramp from initial_flow up to final_flow and back down, over end_time."""

    def inlet_flow(self, t):
        t = np.asarray(t, dtype=float)
        half = self.end_time / 2.0
        rising = np.where(t < half, t / half, (self.end_time - t) / half)
        return self.initial_flow + (self.final_flow - self.initial_flow) * rising


def hysteresis(params, friction):
    """Mean p_s on the rising ramp minus on the falling ramp at the same flows [Pa]."""
    faults = FaultSet(bearing_coulomb_friction=friction, bearing_static_friction=friction)
    w = simulate(params, Triangle(5 * L, 30 * L, 0.0, 2.0), faults=faults, record_interval=1e-3)
    flow, p_s, half = w.inlet_flow / L, w['supply_pressure'], len(w.time) // 2
    grid = np.linspace(8.0, 27.0, 40)
    rising = np.interp(grid, flow[1:half], p_s[1:half])
    falling = np.interp(grid, flow[half:][::-1], p_s[half:][::-1])
    return float(np.mean(rising - falling))


def test_bearing_friction_gives_a_hysteresis_loop_in_a_slow_ramp(params):
    frictionless, small, large = (hysteresis(params, f) for f in (0.0, 5.0, 20.0))
    # Friction opposes the main valve: it opens late on the way up, closes late on the way
    # down. The healthy valve only lags the ramp; the loop friction adds grows in
    # proportion to the friction force.
    assert 0.0 < frictionless < 5e3
    assert small > 2.0 * frictionless and large > 5.0 * frictionless
    assert (large - frictionless) / (small - frictionless) == pytest.approx(4.0, rel=0.15)


def test_a_valve_at_rest_under_a_force_below_stiction_stays_at_rest(params):
    faults = FaultSet(bearing_coulomb_friction=10.0, bearing_static_friction=20.0)
    c = coefficients(params, faults)
    state = steady_state(params, 10 * L)
    assert state[X] > 0.0 and state[X_DOT] == 0.0
    held = state.copy()
    held[P_S] += 15.0 / c.supply_force_area  # 15 N more pressure force: below stiction
    assert 14.0 < net_forces(held, c)[0] < 16.0
    assert state_derivative(held, 10 * L, c)[X_DOT] == 0.0
    # A small flow step loads the valve below stiction: it does not creep at all; a
    # larger one breaks it away.
    small, large = state.copy(), state.copy()
    advance(small, np.full(20000, 10.02 * L), c, 1e-5)
    advance(large, np.full(20000, 12.0 * L), c, 1e-5)
    assert small[X] == state[X] and small[X_DOT] == 0.0
    assert abs(net_forces(small, c)[0]) < 20.0
    assert large[X] != state[X]  # broke away (and swings on the main mode)


def test_a_weakened_pilot_spring_lowers_the_cracking_pressure_in_proportion(params, healthy):
    preset = cracking_pressure(params)
    for weakening in (0.1, 0.2, 0.4):
        faults = FaultSet(pilot_spring_weakening=weakening)
        # In proportion to the spring's preload force; the poppet's lift and flow force at
        # cracking add a little (2 % at 40 %).
        ratio = cracking_pressure(params, faults) / preset
        assert ratio == pytest.approx(1 - weakening, rel=0.025)
    weak = simulate(params, faults=FaultSet(pilot_spring_weakening=0.2))
    ratio = weak['supply_pressure'][-1] / healthy['supply_pressure'][-1]
    assert ratio == pytest.approx(0.8, rel=0.01)
    assert params['pilot_spring_preload'] == load_parameters().params['pilot_spring_preload']


def test_seat_leakage_lowers_p_s_and_moves_cracking_to_a_higher_inlet_flow(params):
    leak = FaultSet(seat_leakage_diameter=0.3e-3)
    assert steady_state(params, 20 * L, leak)[P_S] < steady_state(params, 20 * L)[P_S]
    ramp = FlowStep(0.3 * L, 3 * L, 0.0, 4.0, ramp_time=4.0)
    cracking_flow = {}
    for faults in (HEALTHY, leak):
        w = simulate(params, ramp, faults=faults)
        cracking_flow[faults] = w.inlet_flow[np.argmax(w['main_valve_displacement'] > 0.0)]
    leakage = seat_leakage_flow(cracking_pressure(params), coefficients(params, leak))
    assert cracking_flow[leak] - cracking_flow[HEALTHY] == pytest.approx(leakage, rel=0.02)


BENCH_LIMIT = 21e6  # [Pa] a bench supply relieving at 3x the 7 MPa preset


def test_a_stuck_main_valve_drives_p_s_to_the_supply_limit_without_failing(params):
    stuck = FaultSet(main_valve_stuck=True)
    w = simulate(dict(params, supply_pressure_limit=BENCH_LIMIT), faults=stuck)
    x, p_s = w['main_valve_displacement'], w['supply_pressure']
    assert np.all(x == x[0]) and x[0] > 0.0
    assert np.all(np.diff(p_s[w.time > 0.25]) >= -1e-3 * BENCH_LIMIT)
    assert p_s[-1] == BENCH_LIMIT and np.all(p_s <= BENCH_LIMIT)
    # Without a supply limit p_s rises until the valve's burst_pressure: an overpressure
    # (the physical limit, issue 10), not a numerical failure.
    assert params['supply_pressure_limit'] == 0.0
    with pytest.raises(OverpressureError, match='burst_pressure'):
        simulate(params, faults=stuck)


def test_a_valve_that_sticks_mid_run_stays_where_it_stuck(params):
    schedule = parse_schedule({'events': [{'t': 0.2505, 'set': {'fault.main_valve_stuck': True}}]})
    # the bench supply's relief keeps p_s below the valve's burst_pressure
    w = simulate(dict(params, supply_pressure_limit=BENCH_LIMIT), schedule=schedule)
    stuck_at = np.searchsorted(w.time, 0.251 - 1e-9)  # the first tick at or after 0.2505 s
    x = w['main_valve_displacement']
    assert np.all(x[stuck_at:] == x[stuck_at]) and x[stuck_at - 1] != x[stuck_at - 2]
    assert np.all(w['main_valve_velocity'][stuck_at:] == 0.0)


def test_bad_faults_and_schedules_are_refused_with_the_name_at_fault():
    with pytest.raises(ParameterError, match='fault.damping_orifice_blockage'):
        FaultSet().changed({'fault.damping_orifice_blockage': 1.5})
    with pytest.raises(ParameterError, match="unknown fault 'fault.spring'"):
        FaultSet().changed({'fault.spring': 0.1})
    with pytest.raises(ParameterError, match='must be true or false'):
        FaultSet().changed({'fault.main_valve_stuck': 1})
    with pytest.raises(ParameterError, match='event 2: t must be'):
        parse_schedule({'events': [{'t': 0, 'set': {'fault.main_valve_stuck': True}},
                                   {'t': -1, 'set': {'fault.main_valve_stuck': True}}]})
    with pytest.raises(ParameterError, match='event 1: .*noise_std'):
        parse_schedule({'events': [{'t': 0, 'set': {'sensor.supply_pressure.noise_std': -1}}]})
    with pytest.raises(ParameterError, match='neither a fault'):
        parse_schedule({'events': [{'t': 0, 'set': {'bulk_modulus': 1e9}}]})
    assert set(FAULT_NAMES) == {'fault.' + f.name for f in fields(FaultSet)}


def test_simulate_takes_faults_sensors_and_schedules_from_set_params_and_file(
    tmp_path, capsys, params
):
    from valve_sim.commands.cli import main
    from valve_sim.core.parameters import config_path

    settings = tmp_path / 'faulty.yaml'
    settings.write_text(
        'relief_valve:\n  ros__parameters:\n    fault:\n      damping_orifice_blockage: 0.1\n'
        '    sensor:\n      supply_pressure:\n        noise_std: 1000.0\n'
    )
    assert main(['simulate', '--params', str(settings), '--json']) == 0
    blocked = json.loads(capsys.readouterr().out)
    direct = measures(simulate(params, faults=FaultSet(damping_orifice_blockage=0.1))).values
    assert blocked['P_1_percent'] == pytest.approx(direct['P_1_percent'], rel=1e-12)
    assert main(['simulate', '--set', 'fault.main_valve_stuck=true', '--set',
                 f'supply_pressure_limit={BENCH_LIMIT}', '--json']) == 0
    stuck = json.loads(capsys.readouterr().out)
    assert stuck['P_1_percent'] is None
    assert 'fault.main_valve_stuck' in stuck['reasons']['P_1_percent']
    bag = tmp_path / 'scheduled.mcap'
    example = str(config_path('fault_schedule_example.yaml'))
    assert main(['simulate', '--faults', example, '--mcap', str(bag)]) == 0
    assert 'at t = 1.000000 s' in capsys.readouterr().out
    counts = Counter(channel.topic for channel, _, _ in BagReader(bag).messages())
    assert counts['/supply_pressure'] == 1251 and counts['/pilot_pressure'] == 1000  # dropout
    assert main(['study', '--out', str(tmp_path), '--set', 'fault.main_valve_stuck=true']) == 1
    assert 'valve_node and `valve-sim simulate` only' in capsys.readouterr().err


def test_a_fault_is_described_with_its_unit_and_a_fraction_with_none():
    faults = HEALTHY.changed({'fault.damping_orifice_blockage': 0.3,
                              'fault.bearing_coulomb_friction': 5.0})
    assert faults.describe() == (
        'fault.bearing_coulomb_friction = 5 N, fault.damping_orifice_blockage = 0.3'
    )
