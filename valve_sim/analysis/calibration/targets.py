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
What a calibration fits to: a target gives the residuals of a parameter set.

- MeasuresTarget: the six step measures of the paper's test (value and tolerance each),
  or of a recorded step (from_step: that step run by the model, the paper's tolerances);
  residual = weight (model - value) / tolerance.
- RecordingTarget: a recorded step. The model is driven by the recorded inlet flow
  itself (core.simulation.simulate_recorded_flow) and compared with the recorded
  supply pressure, and with the main-valve position where it was recorded;
  residual = (model - recorded) / noise, the noise of each signal estimated from
  its sample-to-sample scatter before the first step.

Both offer kind, residual_names, residuals(params), model_output(params) and
covariance_scale(cost, count, fitted) (the s^2 of the fit's covariance).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
from typing import Any, Optional, TYPE_CHECKING

import numpy as np
from valve_sim.analysis.paper import REFERENCE_FLOW_STEP
from valve_sim.analysis.steps.measures import MEASURE_NAMES, step_measures
from valve_sim.analysis.steps.step_detection import detect_steps
from valve_sim.core.errors import CalibrationError
from valve_sim.core.flow_step import FlowStep
from valve_sim.core.input_files import shown
from valve_sim.core.model import X
from valve_sim.core.simulation import simulate, simulate_recorded_flow, Waveforms

if TYPE_CHECKING:
    from numpy.typing import ArrayLike


UNDEFINED_MEASURE_RESIDUAL = 30.0  # a measure the model's response does not have
# The paper's tolerances (config/calibration/figure5.json), in each measure's unit: those of a
# measure taken from a recording (MeasuresTarget.from_step, calibration.verdict).
PAPER_TOLERANCES = {'P_o_percent': 0.0432, 'P_1_percent': 0.477, 'T_1_ms': 0.67, 'r_d': 0.03,
                    'T_d_ms': 2.51, 'T_s_ms': 108.0}


class MeasuresTarget:
    """
    The six measures of the paper's step test (or a subset), each with value and tolerance.

    values, tolerances, weights: {measure name: number}; tolerance in the measure's unit.
    """

    kind = 'measures'

    def __init__(self, values: Mapping[str, float], tolerances: Mapping[str, float],
                 weights: Optional[Mapping[str, float]] = None,
                 flow_step: FlowStep = REFERENCE_FLOW_STEP, step_size: float = 1e-5) -> None:
        self.names = [name for name in MEASURE_NAMES if name in values]
        self.values = {name: float(values[name]) for name in self.names}
        self.tolerances = {name: float(tolerances[name]) for name in self.names}
        self.weights = {name: float((weights or {}).get(name, 1.0)) for name in self.names}
        self.flow_step, self.step_size = flow_step, step_size
        self.residual_names = list(self.names)

    @classmethod
    def from_document(cls, document, step_size=1e-5):
        """
        Build from {name: value} or {name: {"value", "tolerance", "weight"}} (JSON).

        A bare value gets a tolerance of 10 % of itself. Raises CalibrationError.
        """
        if not isinstance(document, dict):
            raise CalibrationError('a measures target must map measure names to values')
        values, tolerances, weights = {}, {}, {}
        unknown = sorted(set(document) - set(MEASURE_NAMES) - {'comment', 'source'})
        if unknown:
            raise CalibrationError(
                f'unknown measure(s) {", ".join(unknown)}; known: {", ".join(MEASURE_NAMES)}'
            )
        for name in MEASURE_NAMES:
            if name not in document:
                continue
            entry = document[name]
            entry = entry if isinstance(entry, dict) else {'value': entry}
            try:
                values[name] = float(entry['value'])
                tolerances[name] = float(entry.get('tolerance', 0.1 * abs(values[name])))
                weights[name] = float(entry.get('weight', 1.0))
            except (KeyError, TypeError, ValueError):
                raise CalibrationError(
                    f"measure {name}: need a number or {{'value': number, 'tolerance': number, "
                    f"'weight': number}}, got {shown(entry)}"
                ) from None
            numbers = (values[name], tolerances[name], weights[name])
            for what, number in zip(('value', 'tolerance', 'weight'), numbers):
                if not math.isfinite(number):
                    raise CalibrationError(f'measure {name}: {what} must be finite')
            if tolerances[name] <= 0.0 or weights[name] <= 0.0:
                raise CalibrationError(f'measure {name}: tolerance and weight must be > 0')
        if not values:
            raise CalibrationError('the measures target names none of ' + ', '.join(MEASURE_NAMES))
        return cls(values, tolerances, weights, step_size=step_size)

    @classmethod
    def from_step(cls, records, number=1, step_size=1e-5):
        """
        Build from step number (from 1) of step records, with the paper's tolerances.

        records: analyse --json's or a bag's. The model runs the same step (flow_before ->
        flow_after, from its steady state, a full window); the record's undefined
        measures are left out.
        """
        if not 1 <= number <= len(records) or not isinstance(records[number - 1], dict):
            raise CalibrationError(f'no step {number}: the recording has {len(records)} step(s)')
        record = records[number - 1]
        if record.get('flow_before') is None or record.get('flow_after') is None:
            raise CalibrationError('the step record has no flow_before and flow_after (an '
                                   'analyse --json output of this version has them)')
        values = {name: record[name] for name in MEASURE_NAMES if record.get(name) is not None}
        if not values:
            raise CalibrationError('the step has none of the six measures: '
                                   + '; '.join(f'{k}: {v}' for k, v in record['reasons'].items()))
        flow_step = FlowStep(float(record['flow_before']), float(record['flow_after']),
                             REFERENCE_FLOW_STEP.step_time, REFERENCE_FLOW_STEP.end_time)
        return cls(values, PAPER_TOLERANCES, flow_step=flow_step, step_size=step_size)

    def model_output(self, params: Mapping[str, float]) -> tuple[dict[str, Any], Waveforms]:
        """Measures (StepMeasures.as_dict) and waveforms of the model's step test."""
        waveforms = simulate(params, self.flow_step, self.step_size, 1e-4)
        measures = step_measures(
            waveforms.time,
            waveforms['supply_pressure'],
            waveforms['main_valve_displacement'],
            self.flow_step.step_time,
            1 if self.flow_step.final_flow >= self.flow_step.initial_flow else -1,
        ).as_dict()
        return measures, waveforms

    def residuals(self, params: Mapping[str, float]) -> np.ndarray:
        measures, _ = self.model_output(params)
        return np.array(
            [
                self.weights[name] * (measures[name] - self.values[name]) / self.tolerances[name]
                if measures[name] is not None
                else UNDEFINED_MEASURE_RESIDUAL
                for name in self.names
            ]
        )

    def covariance_scale(self, cost: float, count: int, fitted: int) -> float:
        """Residuals are in tolerance units: s^2 = 1."""
        return 1.0


def noise_level(signal, count):
    """
    Robust standard deviation [signal unit] of white noise on the first count samples.

    Differences with a non-finite end (a sample not recorded) are left out.
    """
    differences = np.diff(np.asarray(signal[:count], dtype=float))
    differences = differences[np.isfinite(differences)]
    if len(differences) < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(differences - np.median(differences))) / math.sqrt(2))


class RecordingTarget:
    """
    A recorded step: time [s], supply pressure [Pa gauge], inlet flow [m^3/s], main valve [m].

    main_valve may be None (a rig without a position sensor) or hold NaN where not
    recorded. inlet_flow[i] is the flow over the interval ending at time[i].
    step_times [s]: steps located between two flow samples (a flowmeter slower than the
    pressure, see step_detection.locate_step), brackets [(first, last)] [s] those samples'
    times: the recorded flow changes only at the sample at last, the model's at the step
    time. Located times are uncertain: step_time_parameters() fits them along with the
    parameters, inside their brackets.
    """

    kind = 'recording'

    @classmethod
    def from_recording(cls, recording: Any, step_size: float = 1e-5) -> RecordingTarget:
        """
        Return the target of a recording (recording.signal_reader.Recording).

        Times count from its first row; the main valve counts where the recording holds
        it at all; steps the pressure locates between two flow samples (located_steps)
        are fitted too. The recording's rows must each hold every signal: cut it with
        signal_reader.from_every_signal first, as `valve-sim calibrate` does.
        """
        start = recording.time[0]
        main_valve = recording.main_valve if np.any(np.isfinite(recording.main_valve)) else None
        located = located_steps(recording)
        return cls(
            recording.time - start,
            recording.supply_pressure,
            recording.inlet_flow,
            main_valve,
            step_size,
            step_times=[t - start for t, _ in located],
            brackets=[tuple(t - start for t in bracket) for _, bracket in located],
        )

    def __init__(self, time: ArrayLike, supply_pressure: ArrayLike, inlet_flow: ArrayLike,
                 main_valve: Optional[ArrayLike] = None, step_size: float = 1e-5,
                 step_threshold: float = 1e-6, step_times: Sequence[float] = (),
                 brackets: Sequence[tuple[float, float]] = ()) -> None:
        time = np.asarray(time, dtype=float)
        pressure = np.asarray(supply_pressure, dtype=float)
        flow = np.asarray(inlet_flow, dtype=float)
        if not (len(time) == len(pressure) == len(flow)) or len(time) < 10:
            raise CalibrationError('a recording needs at least 10 joined samples')
        if not (np.all(np.isfinite(pressure)) and np.all(np.isfinite(flow))):
            raise CalibrationError('the recording holds NaN or infinite pressure or flow samples')
        if np.any(np.diff(time) < step_size):
            raise CalibrationError(
                f'sample times must increase by at least the step size {step_size:g} s'
            )
        if np.any(flow < 0.0):
            raise CalibrationError('the recorded inlet flow is negative somewhere')
        self.steps = detect_steps(time, flow, step_threshold)
        if not self.steps:
            raise CalibrationError(
                f'no usable step: the recorded inlet flow stays within {step_threshold:g} m^3/s '
                f'of {flow[0]:g} m^3/s over {time[-1] - time[0]:.3f} s, so the recording shows '
                'no dynamics to fit (record a flow step)'
            )
        first_step = min([self.steps[0][0], *step_times])  # a located one can come earlier
        before = max(int(np.searchsorted(time, first_step, side='right')), 2)
        self.time, self.pressure, self.flow, self.step_size = time, pressure, flow, step_size
        self.step_times = list(step_times)  # located steps [s], fitted (step_time_parameters)
        self.brackets = list(brackets)  # [(first, last)] [s]: where each step time can lie
        self.pressure_noise = max(noise_level(pressure, before), 1.0)  # [Pa] floor: 1 Pa
        self.position = None
        self.residual_names = ['supply_pressure'] * len(time)
        if main_valve is not None:
            position = np.asarray(main_valve, dtype=float)
            if np.any(np.isinf(position)):
                raise CalibrationError('the recorded main-valve position is infinite somewhere')
            if np.any(np.isfinite(position)):
                self.position = position
                self.position_noise = max(noise_level(position, before), 1e-9)  # [m]
                recorded = np.isfinite(position)
                self.residual_names += ['main_valve'] * int(recorded.sum())

    def model_output(self, params: Mapping[str, float]) -> np.ndarray:
        """Model states (rows) at the recorded sample times."""
        flow = self.flow.copy()
        for t_step, (_, last) in zip(self.step_times, self.brackets):
            after = min(int(np.searchsorted(self.time, last)), len(flow) - 1)
            flow[(self.time > t_step) & (self.time < last)] = flow[after]  # the new flow
        return simulate_recorded_flow(params, self.time, flow, self.step_size, self.step_times)

    def residuals(self, params: Mapping[str, float]) -> np.ndarray:
        states = self.model_output(params)
        parts = [(states[:, 0] - self.pressure) / self.pressure_noise]
        if self.position is not None:
            recorded = np.isfinite(self.position)
            parts.append((states[recorded, X] - self.position[recorded]) / self.position_noise)
        return np.concatenate(parts)

    def covariance_scale(self, cost: float, count: int, fitted: int) -> float:
        """s^2: the residual variance, for noise levels that were only estimated."""
        return 2.0 * cost / max(count - fitted, 1)


def located_steps(recording: Any) -> list:
    """
    Return [(step time, (first, last))] [s] of the steps analyse locates between flow samples.

    A flowmeter slower than the pressure shows a step only at its next sample (last);
    analyse locates it from the pressure (step_detection.locate_step), and calibrate fits it.
    """
    from valve_sim.analysis.recorded_steps import analyse

    return [
        (record['t_step'], tuple(record['details']['t_step_bracket']))
        for record in analyse(recording)
        if record['details'].get('t_step_from') == 'supply_pressure'
    ]
