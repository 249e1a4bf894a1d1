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

"""The reference valve as real valves are built, its study relieving, its modes explained."""

import math
from pathlib import Path
import re

import pytest
from valve_sim.analysis.calibration.requirements import StudyRelieves
from valve_sim.analysis.paper import TABLE2_CHANGES
from valve_sim.analysis.studies.cases import case_parameters
from valve_sim.core.linear import mode_sensitivity, modes
from valve_sim.core.parameters import load_parameters
from valve_sim.core.simulation import LITRE_PER_MINUTE
from valve_sim.core.steady_state import with_preset_pressure


ROOT = Path(__file__).resolve().parents[2]
# The design rules of docs/model.md ("The main stage as built"), as the documented
# calibrate command imposes them: the wall between the guide bore and a land [m], the
# main spring's rate [N/m] and preload force [N].
LAND_MARGIN = 1e-3
SPRING_RATE = (1e3, 5e3)
SPRING_PRELOAD = (20.0, 100.0)
PRESET = 7e6


@pytest.fixture(scope='module')
def reference():
    return load_parameters().params


def documented_command():
    """Return the calibrate command of docs/model.md, on one line."""
    text = re.sub(r'\s*\\\n\s*', ' ', (ROOT / 'docs' / 'model.md').read_text())
    return re.search(r'valve-sim calibrate --params config/calibration/figure5_start\.yaml[^\n]*',
                     text).group(0)


def test_the_design_rules_are_the_documented_commands():
    command = documented_command()

    def option(name):
        return [float(v) for v in re.search(f'--{name} (\\S+)', command).group(1).split(':')]

    assert option('land-margin') == [LAND_MARGIN]
    assert option('main-spring-rate') == list(SPRING_RATE)
    assert option('main-spring-preload') == list(SPRING_PRELOAD)


def test_the_lands_sit_inside_the_guide_bore(reference):
    bore = reference['main_valve_back_diameter']
    for land in ('first_throttle', 'second_throttle'):
        outer, inner = (reference[f'{land}_{edge}_diameter'] for edge in ('outer', 'inner'))
        assert inner < outer <= bore - 2.0 * LAND_MARGIN, land


def test_the_main_spring_is_a_soft_one(reference):
    rate = reference['main_spring_stiffness']
    preload = rate * reference['main_spring_preload']
    assert SPRING_RATE[0] <= rate <= SPRING_RATE[1]
    assert SPRING_PRELOAD[0] <= preload <= SPRING_PRELOAD[1]
    # Enough to close the unpressurised valve: more than its weight, by far.
    assert preload > 10.0 * reference['main_valve_mass'] * 9.81


def test_every_study_case_opens_the_main_stage_and_relieves(reference):
    failed, largest = StudyRelieves().failures(reference)
    assert failed == []
    assert largest < 0.01  # p_s before the step within 1 % of the held preset


@pytest.mark.parametrize('flow_lpm', (5.0, 20.0))
def test_every_linear_mode_of_the_table2_case_decays(reference, flow_lpm):
    table2 = case_parameters(reference, TABLE2_CHANGES, 'held-preset', PRESET)
    found = modes(table2, flow_lpm * LITRE_PER_MINUTE)
    assert len(found) == 5  # 3 oscillatory pairs and 2 real ones: all 8 eigenvalues
    for mode in found:
        assert mode.decay_rate >= 3.0, mode  # 95 % within the measures' 1 s window
    assert [m.name for m in found if m.frequency_hz > 0] == [
        'main stage', 'pilot poppet', 'main valve on V_p'
    ]


@pytest.mark.parametrize('name', (
    'sensing_rod_diameter', 'damping_orifice_diameter', 'supply_volume',
    'pilot_spring_stiffness', 'first_throttle_inner_diameter', 'main_valve_mass',
))
def test_mode_sensitivity_is_the_finite_difference_of_the_modes(reference, name):
    """Per +1 %: the table's change equals a finite difference of modes() with a smaller step."""
    flow = 20 * LITRE_PER_MINUTE
    base, table = mode_sensitivity(reference, flow, PRESET, names=[name])
    step = 0.25  # [%]
    moved = [
        modes(with_preset_pressure({**reference, name: reference[name] * (1 + s * step / 100)},
                                   PRESET), flow)
        for s in (1, -1)
    ]
    for k, mode in enumerate(base):
        up, down = (min(m, key=lambda c: abs(c.eigenvalue - mode.eigenvalue)) for m in moved)
        frequency = (up.frequency_hz - down.frequency_hz) / (2 * step)
        decay = (up.decay_rate - down.decay_rate) / (2 * step)
        change_f, change_decay = table[name][k]
        scale_f = 1e-3 * mode.frequency_hz + 1e-3  # 0.1 % of the frequency per 1 %
        scale_decay = 1e-3 * mode.decay_rate + 1e-3
        assert change_f == pytest.approx(frequency, rel=0.05, abs=scale_f), (name, mode.name)
        assert change_decay == pytest.approx(decay, rel=0.05, abs=scale_decay), (name, mode.name)


def test_parameters_outside_the_linear_dynamics_have_no_mode_sensitivity(reference):
    base, table = mode_sensitivity(reference, 20 * LITRE_PER_MINUTE, PRESET,
                                   names=['poppet_stroke', 'main_valve_stroke'])
    for changes in table.values():  # zero but for the preset's re-solve (residual 1e-9)
        for mode, (df, decay) in zip(base, changes):
            assert abs(df) + abs(decay) < 1e-9 * abs(mode.eigenvalue)


def test_what_sets_the_main_mode(reference):
    """The documented reading of the table: the main mode's frequency follows V_s^-1/2."""
    base, table = mode_sensitivity(reference, 20 * LITRE_PER_MINUTE, PRESET,
                                   names=['supply_volume', 'bulk_modulus', 'main_valve_mass'])
    main = next(k for k, mode in enumerate(base) if mode.name == 'main stage')
    frequency = base[main].frequency_hz
    # omega^2 ~ gain / C_s, C_s = V_s / beta: -1/2 % and +1/2 % of the frequency per 1 %.
    assert table['supply_volume'][main][0] == pytest.approx(-0.005 * frequency, rel=0.05)
    assert table['bulk_modulus'][main][0] == pytest.approx(0.005 * frequency, rel=0.1)
    assert abs(table['main_valve_mass'][main][0]) < 1e-3 * frequency  # m_m barely matters
    assert math.isfinite(base[main].decay_rate) and base[main].decay_rate > 0
