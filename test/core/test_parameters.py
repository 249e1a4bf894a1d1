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

"""Parameter files, validation and the consistency of the shipped configuration."""

import math

import pytest
from valve_sim.analysis.paper import TABLE2_CHANGES
from valve_sim.core.bearing import reference_bearing_fit
from valve_sim.core.errors import ParameterError
from valve_sim.core.parameters import (
    config_path,
    load_parameters,
    read_parameter_file,
    resolve_name,
    scaled,
    SPECS,
    STANDARD_ATMOSPHERE,
    validate,
)


def test_reference_file_holds_every_parameter_and_the_step_size():
    raw = read_parameter_file(config_path('reference.yaml'))
    assert set(SPECS) <= set(raw)
    loaded = load_parameters()
    params, settings = loaded.params, loaded.settings
    assert settings['step_size'] == 1e-5
    assert (
        settings['ambient_pressure'] == STANDARD_ATMOSPHERE
    )  # the default of every wire reader and writer
    assert all(isinstance(value, float) for value in params.values())


def test_table2_file_is_the_reference_with_the_papers_changes(reference):
    table2 = load_parameters(config_path('table2.yaml')).params
    expected = scaled(reference, TABLE2_CHANGES)
    for name in SPECS:
        assert table2[name] == pytest.approx(expected[name], rel=1e-12), name
    assert sum(table2[name] != reference[name] for name in SPECS) == len(TABLE2_CHANGES)


def test_bearing_coefficients_are_the_fit_of_the_documented_bearing(reference):
    k1, k2, k3, lam, error = reference_bearing_fit(reference)
    assert (
        reference['bearing_coefficient_1'],
        reference['bearing_coefficient_2'],
        reference['bearing_coefficient_3'],
    ) == pytest.approx((k1, k2, k3), rel=1e-9)
    assert error < 0.02 and 0.5 < lam < 3.0  # lam 2.0: the fitted d_b (docs/model.md)


@pytest.mark.parametrize(
    'name, value, message',
    [
        ('main_valve_mass', -0.065, 'outside its limits'),
        ('main_valve_mass', 0.0, 'outside its limits'),
        ('supply_volume', 0.0, 'outside its limits'),
        ('damping_orifice_diameter', -1e-3, 'outside its limits'),
        ('bulk_modulus', math.nan, 'must be finite'),
        ('pilot_spring_stiffness', math.inf, 'must be finite'),
        ('fluid_density', 'water', 'must be a number'),
        ('discharge_coefficient', True, 'must be a number'),
        ('first_throttle_inner_diameter', 0.0209, 'must exceed'),  # D_1 <= d_1
        ('second_throttle_inner_diameter', 0.02071, 'must exceed'),  # D_2 <= d_2
        ('bearing_coefficient_1', -5.0, 'does not\nrise|does not rise'),
    ],
)
def test_invalid_values_are_rejected_naming_parameter_and_limit(reference, name, value, message):
    with pytest.raises(ParameterError, match=message) as error:
        validate(dict(reference, **{name: value}))
    assert f"'{name}'" in str(error.value) or 'bearing coefficients' in str(error.value)


def test_a_file_that_sets_the_retired_swept_inner_diameter_loads_with_a_warning(
    reference, tmp_path, caplog
):
    old = tmp_path / 'old_calibrated.yaml'
    old.write_text('relief_valve:\n  ros__parameters:\n    swept_inner_diameter: 20.8e-3\n'
                   '    main_valve_mass: 0.07\n')
    with caplog.at_level('WARNING'):
        params = load_parameters(old).params
    assert params['main_valve_mass'] == 0.07 and 'swept_inner_diameter' not in params
    assert f'{old}: ignoring swept_inner_diameter = 0.0208' in caplog.text
    assert 'now the supply force area alpha_s' in caplog.text
    for name in ('swept_inner_diameter', 'd_i'):  # --set, a live change: an error saying why
        with pytest.raises(ParameterError, match="'swept_inner_diameter' no longer exists"):
            load_parameters(overrides={name: 0.0208})


def test_unknown_and_missing_names_are_rejected(reference):
    with pytest.raises(ParameterError, match="unknown parameter 'mass'"):
        validate(dict(reference, mass=1.0))
    incomplete = dict(reference)
    del incomplete['supply_volume']
    with pytest.raises(ParameterError, match='missing parameter.*supply_volume'):
        validate(incomplete)


def test_symbols_and_names_both_resolve():
    assert resolve_name('m_m') == 'main_valve_mass'
    assert resolve_name('main_valve_mass') == 'main_valve_mass'
    params = load_parameters(overrides={'d_c': 1.2e-3, 'supply_volume': 0.02}).params
    assert params['damping_orifice_diameter'] == 1.2e-3 and params['supply_volume'] == 0.02


def test_parameter_files_like_ros_writes_them(tmp_path):
    partial = tmp_path / 'p.yaml'
    partial.write_text(
        '/**:\n  ros__parameters:\n    main_valve_mass: 7e-2\n    step_size: 5e-6\n'
    )
    loaded = load_parameters(partial)
    params, settings = loaded.params, loaded.settings
    assert params['main_valve_mass'] == 0.07 and settings['step_size'] == 5e-6


@pytest.mark.parametrize(
    'text, message',
    [
        ('relief_valve: [1, 2', 'not valid YAML'),
        ('- just\n- a list\n', 'must map node names'),
        (
            'other_node:\n  ros__parameters:\n    main_valve_mass: 1.0\n',
            'no section that applies to /relief_valve',
        ),
        ('relief_valve:\n  ros__parameters:\n    step_size: 1.0\n', 'step_size'),
        ('relief_valve:\n  ros__parameters:\n    colour: blue\n', "unknown parameter 'colour'"),
    ],
)
def test_broken_parameter_files_give_clear_errors(tmp_path, text, message):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(ParameterError, match=message):
        load_parameters(path)


def test_preset_pressure_in_a_parameter_file_sets_the_preload(tmp_path):
    from valve_sim.core.steady_state import cracking_pressure, with_preset_pressure

    path = tmp_path / 'rig.yaml'
    path.write_text('relief_valve:\n  ros__parameters:\n    preset_pressure: 8.0e6\n')
    loaded = load_parameters(path)
    params, settings = loaded.params, loaded.settings
    assert settings['preset_pressure'] == 8e6
    assert cracking_pressure(with_preset_pressure(params, 8e6)) == pytest.approx(8e6, rel=1e-9)
    path.write_text('relief_valve:\n  ros__parameters:\n    preset_pressure: -1.0\n')
    with pytest.raises(ParameterError, match="'preset_pressure'.*outside its limits"):
        load_parameters(path)
