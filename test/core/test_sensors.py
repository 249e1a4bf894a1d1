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

"""The sensor stage: what valve_node publishes of the pressures, on numbers alone."""

import math

import numpy as np
import pytest
from valve_sim.core.errors import ParameterError
from valve_sim.core.sensors import PRESSURE_NAMES, SensorStage

TRUE = [7.1e6, 6.0e6, 4.9e6, 2.1e6]  # [Pa absolute]
PERIOD_NS = 1_000_000


def run(stage, samples, pressures=TRUE):
    return np.array([stage.read(k * PERIOD_NS, pressures) for k in range(samples)])


def test_ideal_by_default_and_never_below_vacuum():
    stage = SensorStage()
    assert stage.ideal and stage.describe_faults() == []
    assert stage.read(0, TRUE) == TRUE
    assert stage.read(0, [-2e5, 1.0, 0.0, 3.0]) == [0.0, 1.0, 0.0, 3.0]


def test_noise_has_the_set_standard_deviation_and_bias_the_set_mean():
    stage = SensorStage({'sensor.supply_pressure.noise_std': 2e4,
                         'sensor.supply_pressure.bias': 5e4})
    readings = run(stage, 20000)[:, 0] - TRUE[0]
    assert np.mean(readings) == pytest.approx(5e4, abs=4 * 2e4 / math.sqrt(20000))
    assert np.std(readings) == pytest.approx(2e4, rel=0.03)
    assert np.all(run(stage, 10)[:, 1:] == TRUE[1:])  # the other topics stay ideal


def test_the_same_seed_repeats_a_run_and_another_seed_does_not():
    settings = {f'sensor.{topic}.noise_std': 1e3 for topic in PRESSURE_NAMES}
    first, again = (run(SensorStage(settings), 100) for _ in range(2))
    other = run(SensorStage({**settings, 'sensor.noise_seed': 7}), 100)
    assert np.array_equal(first, again) and not np.array_equal(first, other)
    assert not np.array_equal(first[:, 0], first[:, 1])  # one stream per topic


def test_lag_quantisation_range_stuck_and_dropout():
    stage = SensorStage({'sensor.supply_pressure.bandwidth': 100.0})
    stage.read(0, [1e6] * 4)
    lagged = stage.read(PERIOD_NS, [2e6] * 4)[0]
    assert lagged == pytest.approx(1e6 + 1e6 * (1 - math.exp(-2 * math.pi * 100 * 1e-3)))
    stage.change({'sensor.supply_pressure.bandwidth': 0.0,
                  'sensor.intermediate_pressure.resolution': 1e5,
                  'sensor.pilot_pressure.range_min': 5e6,
                  'sensor.pilot_pressure.range_max': 6e6,
                  'sensor.poppet_chamber_pressure.dropout': True})
    readings = stage.read(2 * PERIOD_NS, TRUE)
    assert readings[:3] == [TRUE[0], 6.0e6, 5e6] and math.isnan(readings[3])
    assert stage.read(3 * PERIOD_NS, [7e6] * 4)[2] == 6e6
    assert stage.dropped_topics() == ['poppet_chamber_pressure']
    stage.change({'sensor.supply_pressure.stuck': True})
    held = stage.read(4 * PERIOD_NS, [1e6] * 4)[0]
    assert held == 7e6 and stage.read(5 * PERIOD_NS, [3e6] * 4)[0] == held
    stage.change({'sensor.supply_pressure.stuck_at': 0.0})
    assert stage.read(6 * PERIOD_NS, TRUE)[0] == 0.0


def test_bad_sensor_settings_name_the_parameter_at_fault():
    stage = SensorStage()
    with pytest.raises(ParameterError, match="'sensor.supply_pressure.noise_std'"):
        stage.change({'sensor.supply_pressure.noise_std': math.nan})
    with pytest.raises(ParameterError, match='range_max.*must exceed'):
        stage.change({'sensor.pilot_pressure.range_min': 2e6,
                      'sensor.pilot_pressure.range_max': 1e6})
    with pytest.raises(ParameterError, match="unknown sensor setting 'sensor.flow.bias'"):
        stage.change({'sensor.flow.bias': 1.0})
    with pytest.raises(ParameterError, match='must be an integer'):
        stage.change({'sensor.noise_seed': 1.5})
    assert stage.ideal  # nothing of a refused change was applied
