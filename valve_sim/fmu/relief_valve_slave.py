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
ReliefValve: the FMU's slave, valve_sim.core's RealTimeModel behind FMI 2.0 co-simulation.

pythonfmu copies this file into the FMU (resources/) and the FMU's binary runs it in an
embedded Python, which must have valve_sim installed (docs/fmu.md). The parameter file
the FMU was built with, resources/parameters.yaml, gives the defaults.

Variables (SI; pressures gauge, above the ambient pressure, as `valve-sim simulate`):
  inputs      inlet_flow q_in [m^3/s], tank_pressure p_t [Pa, gauge]
  outputs     supply_pressure p_s, intermediate_pressure p_m, pilot_pressure p_p,
              poppet_chamber_pressure p_c [Pa, gauge]; main_valve_displacement x,
              poppet_displacement y [m]; relief_flow (all the valve passes to the tank)
              and its parts main_stage_flow q_m2, pilot_flow q_p, seat_leakage_flow q_l
              [m^3/s]; halted (the model holds its last good state)
  parameters  every model parameter of the catalogue and preset_pressure (tunable),
              step_size (the internal RK4 step [s], tunable), initial_state (fixed)

doStep integrates the whole internal steps that fit up to the communication point and
carries the remainder into the next step, as valve_node does (RealTimeModel), so any
communication step works. A parameter change between steps is planned, checked and
trial-run as valve_node plans it (core.retuning.plan_change: the cracking point solved
once), then applied. An overpressure halts the model as it halts valve_node
(supply_pressure at burst_pressure, the rest held): fmi2OK with a logged warning. A
divergence keeps the last good state: fmi2Discard with the reason logged, until an input
or a parameter changes. An invalid input (NaN, negative, beyond the limits) or a refused
parameter change: fmi2Discard, nothing integrated, the reason logged with status error; the
instance stays usable. A failed start raises in exit_initialization_mode: fmi2Error with
the reason (valve_sim's build of pythonfmu's binary, export_binary, makes any exception of
an FMI call fmi2Error with its message, the instance kept for fmi2Terminate, fmi2Reset or
fmi2FreeInstance; it passes warnings and errors to the master whatever its logging setting).

scipy.linalg is imported before valve_sim (and so before numba): loaded after numba, its
Fortran runtime's exit handler aborts a C master at exit (docs/fmu.md).

Over 400 lines on purpose: one class whose methods are the FMI calls, in the one file
pythonfmu copies into the FMU.
"""

from pathlib import Path

from pythonfmu import (
    Boolean,
    DefaultExperiment,
    Fmi2Causality,
    Fmi2Slave,
    Fmi2Variability,
    String,
)
from pythonfmu.enums import Fmi2Status
import scipy.linalg  # noqa: F401 (first: the load order a C master needs, see above)
from valve_sim import __version__
from valve_sim.core.errors import (
    IntegrationError,
    OverpressureError,
    ParameterError,
    SteadyStateError,
)
from valve_sim.core.limits import inlet_flow_problem, tank_pressure_problem
from valve_sim.core.model import STATE_NAMES
from valve_sim.core.parameters import (
    check_value,
    load_parameters,
    PARAMETERS,
    PRESET_PRESSURE,
    SETTING_SPECS,
    SPECS,
)
from valve_sim.core.realtime_model import NS_PER_S, RealTimeModel
from valve_sim.core.retuning import plan_change, planned_parameters
from valve_sim.core.sensors import SensorStage
from valve_sim.core.steady_state import cracking_pressure
from valve_sim.fmu.fmi_calls import advance_streaming, check_step
from valve_sim.fmu.model_description import (
    parameter_description,
    Quantity,
    with_units_and_unknowns,
)


PARAMETER_FILE = 'parameters.yaml'  # in the FMU's resources/: the defaults it was built with
INITIAL_STATES = ('steady', 'closed')
REFUSED = (ParameterError, SteadyStateError, IntegrationError)  # what a start or change meets

OUTPUT_STATES = {  # the states that are outputs: description
    'supply_pressure': 'p_s: supply pressure at the inlet port, gauge',
    'intermediate_pressure': 'p_m: pressure between the main throttles, gauge',
    'pilot_pressure': 'p_p: pilot (back) chamber pressure, gauge',
    'poppet_chamber_pressure': 'p_c: poppet chamber pressure, gauge',
    'main_valve_displacement': 'x: main valve opening from its seat',
    'poppet_displacement': 'y: pilot poppet opening from its seat',
}
OUTPUT_FLOWS = {  # RealTimeModel.relief_flows(), in its order: description
    'relief_flow': 'all the valve passes to the tank: main stage + pilot + seat leakage',
    'main_stage_flow': 'q_m2: flow through the second main throttle to the tank (Eq. 11)',
    'pilot_flow': 'q_p: flow past the pilot poppet to the tank (Eq. 15)',
    'seat_leakage_flow': 'q_l: leakage past the main valve seat (a fault; 0 when healthy)',
}


class ReliefValve(Fmi2Slave):
    """The direct-pressure-sensing water-hydraulic relief valve of valve_sim (one instance)."""

    author = 'valve_sim developers'
    license = 'Apache-2.0; its binary MIT and BSD-2-Clause (documentation/licenses)'  # noqa: A003
    version = __version__
    description = (
        'valve_sim relief valve: inlet flow and tank pressure in; chamber pressures (gauge), '
        'valve positions and the relief flow out. Runs on 64-bit Linux only (one binary, '
        'binaries/linux64), in a Python with valve_sim installed.'
    )
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=1e-3)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.modelName = 'ReliefValve'
        path = Path(self.resources or '.') / PARAMETER_FILE
        loaded = load_parameters(path if path.is_file() else None)
        self._defaults, settings = loaded.params, loaded.settings
        self._default_preset = cracking_pressure(self._defaults)
        self._ambient = settings['ambient_pressure']  # [Pa] the tank is refused below vacuum
        self.model = None
        self._terminated = False
        self._start_ns = 0
        self._clock_ns = None
        self._applied = None  # (inlet flow, tank pressure) of the last step
        self._alarm_logged = None  # the last invariant alarm logged (core.invariants)
        self._saturated = False  # halted by an overpressure: the chamber shown at burst_pressure
        self._failed = None  # why the start failed
        self._sensors = SensorStage()  # ideal, for plan_change: the FMU has no sensor stage
        for spec in PARAMETERS:
            setattr(self, spec.name, self._defaults[spec.name])
            self._parameter(spec)
        self.preset_pressure = self._default_preset
        self._parameter(PRESET_PRESSURE)
        self.step_size = settings['step_size']
        self._parameter(SETTING_SPECS['step_size'])
        self.initial_state = 'steady'
        self.register_variable(String(
            'initial_state', causality=Fmi2Causality.parameter,
            variability=Fmi2Variability.fixed,
            description="start: 'steady' (the exact steady state at the initial inlet_flow and "
            "tank_pressure, as valve_node starts) or 'closed' (the empty, closed valve)",
        ))
        self.inlet_flow = settings['initial_inlet_flow']
        self.tank_pressure = settings['tank_pressure']
        self.register_variable(Quantity(
            'inlet_flow', 'm^3/s', 0.0,  # no max: max_inlet_flow is tunable
            causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
            description='q_in: inlet flow into the supply port, 0 to max_inlet_flow',
        ))
        self.register_variable(Quantity(
            'tank_pressure', 'Pa', causality=Fmi2Causality.input,
            variability=Fmi2Variability.continuous,
            description='p_t: pressure of the tank (return line), gauge: 0 is ambient; '
            'below burst_pressure',
        ))
        for name in OUTPUT_STATES:
            setattr(self, name, 0.0)
            self._output(name, 'Pa' if name.endswith('pressure') else 'm', OUTPUT_STATES)
        for name in OUTPUT_FLOWS:
            setattr(self, name, 0.0)
            self._output(name, 'm^3/s', OUTPUT_FLOWS)
        self.halted = False
        self.register_variable(Boolean(
            'halted', causality=Fmi2Causality.output, variability=Fmi2Variability.discrete,
            description='the model holds its last good state after an overpressure or a '
            'divergence, until an input or a parameter changes',
        ))

    def _parameter(self, spec):
        self.register_variable(Quantity(
            spec.name, spec.unit, spec.minimum, spec.maximum,
            causality=Fmi2Causality.parameter, variability=Fmi2Variability.tunable,
            description=parameter_description(spec),
        ))

    def _output(self, name, unit, descriptions):
        self.register_variable(Quantity(
            name, unit, causality=Fmi2Causality.output,
            variability=Fmi2Variability.continuous, description=descriptions[name],
        ))

    def to_xml(self, model_options=None):
        """Return pythonfmu's XML with the units and initial unknowns (model_description)."""
        return with_units_and_unknowns(super().to_xml(model_options or {}), self.vars.values())

    # --- FMI calls: an exception is fmi2Error with its message (export_binary) ------------

    def setup_experiment(self, start_time, stop_time=None, tolerance=None):
        if not abs(start_time) <= 1e9:
            raise ParameterError(f'startTime must be finite, at most 1e9 s, got {start_time!r}')
        self._start_ns = round(start_time * NS_PER_S)

    def exit_initialization_mode(self):
        """
        Start the model: the steady state at the inputs, or the closed valve.

        Its kernels are compiled (or loaded from numba's cache) here, not in the first
        step. A start that fails raises ParameterError: fmi2Error with the reason.
        """
        if not self._start():
            raise ParameterError(self._failed)

    def do_step(self, current_time, step_size):
        """
        Integrate from current_time over step_size [s]; True: fmi2OK, False: fmi2Discard.

        Discarded, with the reason logged: a step refused (an invalid input, a refused
        parameter change, a start that failed, a step not from the FMU's time, not finite
        or over MAX_COMMUNICATION_STEP, after terminate), of which nothing is integrated,
        and a divergence, of which the last good state is kept. Either way the FMU stays
        at current_time; the master may redo the step.
        """
        try:
            self._step(current_time, step_size)
        except IntegrationError as error:
            self.log(f'{error} The last good state is held; the step is discarded, as are '
                     'the next until an input or a parameter changes.', Fmi2Status.discard)
            return False
        except REFUSED as error:
            self.log(f'doStep at t = {current_time!r} s refused, nothing integrated: {error}',
                     Fmi2Status.error)
            return False
        return True

    def terminate(self):
        self._terminated = True

    def _start(self):
        """Start the model at the inputs as set: True, else False with self._failed why."""
        try:
            if self.initial_state not in INITIAL_STATES:
                raise ParameterError(
                    f"initial_state must be one of {', '.join(INITIAL_STATES)}, "
                    f'got {self.initial_state!r}'
                )
            changes = self._changes(self._defaults, self._default_preset)
            params, _, dependent = planned_parameters(self._defaults, changes)
            preset = {**changes, **dependent}.get('preset_pressure', self._default_preset)
            step_size = check_value('step_size', self.step_size)
            inlet_flow, tank_pressure = self._inputs(params)
            start_flow = inlet_flow if self.initial_state == 'steady' else 0.0
            model = RealTimeModel(params, step_size, start_flow, tank_pressure=tank_pressure,
                                  ambient_pressure=self._ambient)
        except REFUSED as error:
            self._failed = f'the FMU could not start: {error}'
            return False
        self._failed = None
        self.model = model
        compile_kernels(model, start_flow, tank_pressure)
        model.start(self._start_ns)
        self._clock_ns = self._start_ns
        self._applied = (start_flow, tank_pressure)
        self._show(params, preset)
        self._update_outputs()
        return True

    def _step(self, current_time, step_size):
        """do_step's work; raises what refuses the step or IntegrationError."""
        if self._terminated:
            raise ParameterError('doStep after terminate: the instance has ended')
        if self.model is None and not self._start():  # the step says why
            raise ParameterError(self._failed)
        model = self.model
        now_ns = check_step(current_time, step_size, self._clock_ns)
        inlet_flow, tank_pressure = self._inputs(model.params)
        retuned = self._retune(inlet_flow, tank_pressure)
        if retuned or (inlet_flow, tank_pressure) != self._applied:
            self._resume('a parameter change' if retuned else 'a new input')
        self._applied = (inlet_flow, tank_pressure)
        if model.halted is not None and not self._saturated:
            raise IntegrationError('The model is halted after a divergence (logged before).')
        try:
            advance_streaming(model, now_ns, inlet_flow, tank_pressure)
        except OverpressureError as error:
            model.hold_until(now_ns)
            model.halt(str(error))
            self._saturated = error.chamber
            self.log(
                f'{error} The model halts there, as valve_node does: it holds its last good '
                f'state and {error.chamber} is reported at burst_pressure = '
                f"{model.params['burst_pressure']:g} Pa (gauge), the limit it passed, until "
                'an input or a parameter changes', Fmi2Status.warning,
            )
        except IntegrationError as error:
            model.halt(str(error))
            self._update_outputs()
            raise
        self._clock_ns = now_ns
        if model.monitor.last is not None and model.monitor.last is not self._alarm_logged:
            self._alarm_logged = model.monitor.last  # an invariant violated (core.invariants)
            self.log(str(model.monitor.last), Fmi2Status.warning)
        self._update_outputs()

    # --- the adapter -------------------------------------------------------------------------

    def _inputs(self, params):
        """Return the inputs (inlet flow, tank pressure) as floats; ParameterError if invalid."""
        flow, tank = self.inlet_flow, self.tank_pressure
        problem = inlet_flow_problem(flow, params['max_inlet_flow']) or tank_pressure_problem(
            tank, params['burst_pressure'], self._ambient
        )
        if problem:
            raise ParameterError(f'input refused: {problem}')
        return float(flow), float(tank)

    def _changes(self, params, preset, step_size=None):
        """
        Return {name: value} of the parameter variables that differ from those in use, checked.

        params, preset: the model parameters and preset_pressure in use; step_size: the
        step size in use [s] (None: before the start, where it is no change). Setting
        preset_pressure sets pilot_spring_preload, changing a model parameter moves
        preset_pressure, as in valve_node (core.retuning); ParameterError if one is invalid.
        """
        changes = {
            name: getattr(self, name) for name in SPECS if getattr(self, name) != params[name]
        }
        if self.preset_pressure != preset:
            changes['preset_pressure'] = self.preset_pressure
        if step_size is not None and self.step_size != step_size:
            changes['step_size'] = self.step_size
        return {name: check_value(name, value) for name, value in changes.items()}

    def _retune(self, inlet_flow, tank_pressure):
        """Apply changed parameters or step size as valve_node would; True if any changed."""
        model = self.model
        settings = {'step_size': model.step_size, 'tank_pressure': tank_pressure,
                    'ambient_pressure': self._ambient}
        try:
            changes = self._changes(model.params, self._preset, model.step_size)
            if not changes:
                return False
            plan = plan_change(model, settings, changes, inlet_flow, None, self._sensors)
            if plan.problem:
                raise ParameterError(plan.problem)
        except ParameterError as error:
            self._show(model.params, self._preset)
            self.step_size = model.step_size
            raise ParameterError(
                f'parameter change refused, the parameters in use are kept: {error}'
            ) from None
        model.retune(plan.params, plan.settings['step_size'])
        self._show(plan.params, plan.changes.get('preset_pressure', self._preset))
        return True

    def _show(self, params, preset):
        """Set the parameter variables to the parameters in use."""
        for name in SPECS:
            setattr(self, name, params[name])
        self.preset_pressure = self._preset = preset

    def _resume(self, cause):
        if self.model.halted is not None:
            self.model.resume()
            self._saturated = False
            self.log(f'the model advances again after {cause}')

    def _update_outputs(self):
        state = self.model.state
        for index, name in enumerate(STATE_NAMES):
            if name in OUTPUT_STATES:
                setattr(self, name, float(state[index]))
        if self._saturated in OUTPUT_STATES:  # the chamber that passed burst_pressure
            setattr(self, self._saturated, self.model.params['burst_pressure'])
        flows = self.model.relief_flows()
        for name, value in zip(OUTPUT_FLOWS, flows):
            setattr(self, name, float(value))
        self.halted = self.model.halted is not None


def compile_kernels(model, inlet_flow, tank_pressure):
    """Run the integration kernels once on a copy (numba compiles or loads them now)."""
    try:
        model.trial(model.params, model.step_size, inlet_flow, tank_pressure=tank_pressure)
    except IntegrationError:
        pass  # compiled all the same; the divergence is met, and reported, by the steps
