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
Model parameters: names, units, ranges, validation and parameter files.

Every physical parameter of the valve model has one entry in PARAMETERS. The
values themselves live in config/reference.yaml (ROS 2 parameter-file format), so
the command line and the ROS node read the same numbers. All values are SI.

No ROS imports here: the node turns these specs into ParameterDescriptors.
"""

from dataclasses import dataclass
import logging
import math
from pathlib import Path
import sys

from valve_sim.core.errors import InputFileError, ParameterError, SectionError
from valve_sim.core.input_files import PARAMETER_FILE, read_yaml, shown
from valve_sim.core.parameter_sections import describe_not_applied, node_fqn, parameters_for_node


PACKAGE = 'valve_sim'
NODE_NAME = 'relief_valve'


@dataclass(frozen=True)
class ParameterSpec:
    """
    One model parameter.

    name: the ROS parameter name; symbol: the paper's symbol; unit: SI unit;
    minimum/maximum: inclusive physical limits; source: where the value comes from.
    """

    name: str
    symbol: str
    unit: str
    minimum: float
    maximum: float
    description: str
    source: str

    def describe(self):
        return f'{self.description} ({self.symbol}) [{self.unit}]'


TABLE1 = 'paper, Table 1'
OURS = 'our choice, see docs/model.md'

PARAMETERS = (
    # Fluid (water at about 50 degC), Table 1.
    ParameterSpec('fluid_density', 'rho', 'kg/m^3', 500.0, 2000.0, 'fluid density', TABLE1),
    ParameterSpec(
        'fluid_viscosity', 'mu', 'Pa*s', 1e-5, 1.0, 'dynamic viscosity of the fluid', TABLE1
    ),
    ParameterSpec('bulk_modulus', 'beta', 'Pa', 1e7, 1e10, 'bulk modulus of the fluid', TABLE1),
    ParameterSpec(
        'discharge_coefficient',
        'C_d',
        '1',
        0.1,
        1.0,
        'discharge coefficient of the valve throttles, damping orifice and poppet',
        TABLE1,
    ),
    ParameterSpec(
        'bearing_discharge_coefficient',
        'C_b',
        '1',
        0.1,
        1.0,
        'discharge coefficient of the hydrostatic bearing orifices',
        TABLE1,
    ),
    # Moving parts, Table 1.
    ParameterSpec(
        'main_valve_mass',
        'm_m',
        'kg',
        1e-4,
        10.0,
        'mass of the main valve incl. 1/3 of its spring',
        TABLE1,
    ),
    ParameterSpec(
        'pilot_poppet_mass',
        'm_p',
        'kg',
        1e-5,
        1.0,
        'mass of the pilot poppet incl. 1/3 of its spring',
        TABLE1,
    ),
    ParameterSpec(
        'main_valve_damping',
        'c_m',
        'N*s/m',
        0.0,
        1e4,
        'viscous damping coefficient of the main valve',
        TABLE1,
    ),
    ParameterSpec(
        'pilot_poppet_damping',
        'c_p',
        'N*s/m',
        0.0,
        1e4,
        'viscous damping coefficient of the pilot poppet',
        TABLE1,
    ),
    ParameterSpec(
        'pilot_spring_stiffness', 'k_p', 'N/m', 1.0, 1e8, 'pilot spring constant', TABLE1
    ),
    ParameterSpec(
        'damping_orifice_diameter',
        'd_c',
        'm',
        1e-5,
        0.02,
        'damping orifice diameter between pilot chamber and poppet chamber',
        TABLE1,
    ),
    # Chamber volumes, Table 1.
    ParameterSpec(
        'supply_volume',
        'V_s',
        'm^3',
        1e-9,
        10.0,
        'supply volume (valve inlet and connected line)',
        TABLE1,
    ),
    ParameterSpec(
        'intermediate_volume',
        'V_m',
        'm^3',
        1e-9,
        1.0,
        'volume between the two main throttles',
        TABLE1,
    ),
    ParameterSpec(
        'pilot_volume',
        'V_p',
        'm^3',
        1e-9,
        1.0,
        'pilot chamber volume behind the main valve',
        TABLE1,
    ),
    ParameterSpec(
        'poppet_chamber_volume',
        'V_c',
        'm^3',
        1e-9,
        1.0,
        'poppet chamber volume between damping orifice and pilot poppet',
        TABLE1,
    ),
    # Main valve geometry (paper Figure 2, values not printed).
    ParameterSpec(
        'main_valve_back_diameter',
        'd_p',
        'm',
        1e-4,
        0.2,
        'main valve diameter on the pilot-chamber side (A_p = pi/4 d_p^2)',
        OURS,
    ),
    ParameterSpec(
        'first_throttle_outer_diameter',
        'D_1',
        'm',
        1e-4,
        0.2,
        'outer diameter of the first (upstream) annular throttle land',
        OURS,
    ),
    ParameterSpec(
        'first_throttle_inner_diameter',
        'd_1',
        'm',
        1e-4,
        0.2,
        'inner diameter of the first annular throttle land',
        OURS,
    ),
    ParameterSpec(
        'second_throttle_outer_diameter',
        'D_2',
        'm',
        1e-4,
        0.2,
        'outer diameter of the second (downstream) annular throttle land',
        OURS,
    ),
    ParameterSpec(
        'second_throttle_inner_diameter',
        'd_2',
        'm',
        1e-4,
        0.2,
        'inner diameter of the second annular throttle land',
        OURS,
    ),
    ParameterSpec(
        'first_throttle_clearance',
        'h',
        'm',
        0.0,
        1e-3,
        'opening of the first throttle when the main valve is seated (x = 0)',
        OURS,
    ),
    ParameterSpec(
        'main_spring_stiffness', 'k_m', 'N/m', 0.0, 1e8, 'main valve spring constant', OURS
    ),
    ParameterSpec(
        'main_spring_preload',
        'x_0',
        'm',
        0.0,
        0.05,
        'initial compression of the main spring at x = 0',
        OURS,
    ),
    ParameterSpec(
        'main_valve_stroke', 'x_max', 'm', 1e-5, 0.05, 'main valve stroke to its end stop', OURS
    ),
    # Hydrostatic bearings, Eq. (12).
    ParameterSpec(
        'bearing_orifice_diameter',
        'd_b',
        'm',
        1e-5,
        0.01,
        'diameter of one hydrostatic bearing orifice',
        OURS,
    ),
    ParameterSpec(
        'bearing_coefficient_1',
        'K_1',
        '1',
        -1e3,
        1e3,
        'first-order coefficient of the bearing flow polynomial, Eq. (12)',
        OURS,
    ),
    ParameterSpec(
        'bearing_coefficient_2',
        'K_2',
        '1',
        -1e3,
        1e3,
        'second-order coefficient of the bearing flow polynomial, Eq. (12)',
        OURS,
    ),
    ParameterSpec(
        'bearing_coefficient_3',
        'K_3',
        '1',
        -1e3,
        1e3,
        'third-order coefficient of the bearing flow polynomial, Eq. (12)',
        OURS,
    ),
    # Pilot stage geometry (paper Figure 3, values not printed).
    ParameterSpec(
        'sensing_rod_diameter',
        'd_s',
        'm',
        1e-4,
        0.05,
        'diameter of the pressure-detecting rod (A_s = pi/4 d_s^2)',
        OURS,
    ),
    ParameterSpec(
        'sensing_rod_clearance',
        'delta_s',
        'm',
        0.0,
        1e-3,
        'radial clearance between pressure-detecting rod and sleeve',
        OURS,
    ),
    ParameterSpec(
        'sensing_rod_length', 'l_s', 'm', 1e-4, 0.2, 'axial length of the rod clearance', OURS
    ),
    ParameterSpec(
        'pilot_seat_diameter', 'd_v', 'm', 1e-4, 0.02, 'pilot poppet seat diameter', OURS
    ),
    ParameterSpec(
        'poppet_half_angle',
        'theta_p',
        'rad',
        0.01,
        1.56,
        'half cone angle of the pilot poppet',
        OURS,
    ),
    ParameterSpec(
        'pilot_spring_preload',
        'y_0',
        'm',
        0.0,
        0.05,
        'initial compression of the pilot spring at y = 0 (set by the adjusting screw)',
        OURS,
    ),
    ParameterSpec(
        'poppet_stroke', 'y_max', 'm', 1e-5, 0.01, 'pilot poppet stroke to its end stop', OURS
    ),
    # Physical limits of the valve (docs/model.md, "Physical limits").
    ParameterSpec(
        'max_inlet_flow',
        'q_in,max',
        'm^3/s',
        1e-6,
        10.0,  # up to 6e5 L/min: a bench may lift the input limit and leave burst_pressure
        'largest inlet flow the valve accepts; a larger one is rejected as input',
        OURS,
    ),
    ParameterSpec(
        'burst_pressure',
        'p_burst',
        'Pa',
        1e6,
        1e9,
        'gauge pressure no chamber of the valve reaches: the real body would have burst '
        '(a state beyond it is an overpressure)',
        OURS,
    ),
    # The test bench's supply (not the valve).
    ParameterSpec(
        'supply_pressure_limit',
        'p_s,max',
        'Pa',
        0.0,
        5e8,
        "highest supply pressure (gauge) the bench's supply delivers: its own relief "
        'takes the inflow beyond it; where a valve fault drives p_s there, valve_node '
        "raises an overpressure alarm. Set it to your bench's relief setting; 0: no limit",
        OURS,
    ),
    # Numerical regularisation.
    ParameterSpec(
        'orifice_transition_pressure',
        'dp_tr',
        'Pa',
        1.0,
        1e6,
        'pressure drop below which orifice laws turn linear '
        '(closed-valve start under fixed-step RK4)',
        OURS,
    ),
)

# [Pa] the ambient (atmospheric) absolute pressure by default: the ambient_pressure of
# config/reference.yaml, the zero of the model's gauge pressures, and the default of every
# reader and writer of absolute pressures on the wire.
STANDARD_ATMOSPHERE = 101325.0

# Run-time settings that share the parameter files with the model parameters.
SETTINGS = (
    ParameterSpec(
        'step_size',
        'dt',
        's',
        1e-7,
        1e-4,
        "fixed RK4 integration step (the paper's is 10 us)",
        'paper, Method for Simulation',
    ),
    ParameterSpec(
        'publish_rate', 'f_pub', 'Hz', 1.0, 1e4, 'valve_node tick and publish rate', OURS
    ),
    ParameterSpec(
        'initial_inlet_flow',
        'q_in,0',
        'm^3/s',
        0.0,
        0.01,
        'inlet flow whose exact steady state the node starts from',
        'paper, Conditions for Calculation (5 L/min)',
    ),
    ParameterSpec(
        'input_timeout',
        't_timeout',
        's',
        0.0,
        3600.0,
        'inlet_flow silence after which the node reports stale input (0 disables)',
        OURS,
    ),
    ParameterSpec(
        'ambient_pressure',
        'p_atm',
        'Pa',
        0.0,
        2e5,
        "absolute ambient pressure: the zero of the model's gauge pressures, added to them on "
        'the wire; the tank is at it unless tank_pressure says otherwise',
        OURS,
    ),
    ParameterSpec(
        'tank_pressure',
        'p_t',
        'Pa',
        -2e5,
        1e9,
        'gauge pressure of the tank (return line) the valve relieves into, for a pressurised '
        'tank; the tank_pressure topic, once a message came, takes precedence. 0: the tank at '
        'ambient_pressure. Not below vacuum, below burst_pressure',
        'our addition, see docs/model.md ("Back pressure")',
    ),
)

# The adjusting screw, in the parameter files and on every command line: when given, it sets
# pilot_spring_preload (steady_state.with_preset_pressure), as valve_node's parameter does.
PRESET_PRESSURE = ParameterSpec(
    'preset_pressure',
    'p_set',
    'Pa',
    0.0,
    1e8,
    'preset pressure: supply pressure (gauge) at which the main valve cracks open; '
    'setting it sets pilot_spring_preload, like turning the adjusting screw',
    'our definition, see docs/model.md (the paper presets 7 MPa)',
)

SPECS = {spec.name: spec for spec in PARAMETERS}
SETTING_SPECS = {spec.name: spec for spec in SETTINGS}
SYMBOLS = {spec.symbol: spec.name for spec in PARAMETERS}

# Pairs (larger, smaller) that must hold strictly: a land's outer diameter exceeds
# its inner one, and the lands lie inside the valve face.
ORDERED_PAIRS = (
    ('first_throttle_outer_diameter', 'first_throttle_inner_diameter'),
    ('second_throttle_outer_diameter', 'second_throttle_inner_diameter'),
    ('main_valve_back_diameter', 'first_throttle_outer_diameter'),
    ('main_valve_back_diameter', 'second_throttle_outer_diameter'),
)


# Parameters that no longer exist, by name and symbol, and why. A parameter file that
# still sets one (an older calibrated.yaml) is read with it ignored and a warning logged;
# naming one anywhere else (--set, a live change) is an error that says why.
RETIRED = {
    'swept_inner_diameter': (
        'the swept area A_m1 of Eq. (1) is now the supply force area alpha_s, derived from '
        'd_p, D_1 and d_1 (docs/model.md, "Areas: what pushes, what sweeps")'
    ),
}
RETIRED_SYMBOLS = {'d_i': 'swept_inner_diameter'}
log = logging.getLogger(__name__)


def retired_reason(name):
    """Say why name (ROS name or symbol) is no parameter any more; None if it is not retired."""
    name = RETIRED_SYMBOLS.get(name, name)
    if name in RETIRED:
        return f"parameter '{name}' no longer exists: {RETIRED[name]}"
    return None


def resolve_name(name):
    """Return the parameter name for a ROS name or a paper symbol (e.g. 'm_m')."""
    if name in SPECS:
        return name
    if name in SYMBOLS:
        return SYMBOLS[name]
    reason = retired_reason(name)
    if reason:
        raise ParameterError(reason)
    raise ParameterError(f"unknown parameter '{name}'; known: {', '.join(SPECS)}")


def without_retired(raw, source):
    """Drop from raw the retired parameters a file sets, each with a logged warning."""
    for name in [n for n in raw if retired_reason(n)]:
        log.warning(f'{source}: ignoring {name} = {raw.pop(name)!r}: {retired_reason(name)}')
    return raw


def check_value(name, value):
    """Return value as a float if it is a finite number inside the parameter's limits."""
    if name == PRESET_PRESSURE.name:
        spec = PRESET_PRESSURE
    else:
        spec = SETTING_SPECS[name] if name in SETTING_SPECS else SPECS[resolve_name(name)]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(
            f"parameter '{spec.name}' ({spec.symbol}) must be a number in {spec.unit}, "
            f'got {shown(value)}'
        )
    value = float(value) if abs(value) <= sys.float_info.max else math.inf
    if not math.isfinite(value):
        raise ParameterError(
            f"parameter '{spec.name}' ({spec.symbol}) must be finite, got {value}"
        )
    if not spec.minimum <= value <= spec.maximum:
        raise ParameterError(
            f"parameter '{spec.name}' ({spec.symbol}) = {value:g} {spec.unit} "
            f'is outside its limits [{spec.minimum:g}, {spec.maximum:g}] {spec.unit}'
        )
    return value


def validate(params):
    """
    Check a complete parameter set; return a new dict of floats or raise ParameterError.

    Checks every value against its limits, that no parameter is missing or unknown,
    the geometric order of the diameters, and that the bearing flow of Eq. (12)
    rises monotonically with the pressure ratio (a fit that does not is unphysical).
    """
    unknown = sorted(set(params) - set(SPECS))
    if unknown:
        resolve_name(unknown[0])
    missing = [name for name in SPECS if name not in params]
    if missing:
        raise ParameterError(f'missing parameter(s): {", ".join(missing)}')
    checked = {name: check_value(name, params[name]) for name in SPECS}
    for larger, smaller in ORDERED_PAIRS:
        if not checked[larger] > checked[smaller]:
            big, small = SPECS[larger], SPECS[smaller]
            raise ParameterError(
                f"parameter '{larger}' ({big.symbol} = {checked[larger]:g} m) must exceed "
                f"'{smaller}' ({small.symbol} = {checked[smaller]:g} m)"
            )
    k1, k2, k3 = (checked[f'bearing_coefficient_{i}'] for i in (1, 2, 3))
    for i in range(101):
        z = i / 100.0
        if k1 + 2.0 * k2 * z + 3.0 * k3 * z * z <= 0.0:
            raise ParameterError(
                f'bearing coefficients K_1..K_3 = {k1:g}, {k2:g}, {k3:g} give a bearing flow '
                f'that does not rise with the pressure drop at 1 - p_p/p_s = {z:.2f} '
                '(Eq. 12 needs K_1 + 2 K_2 z + 3 K_3 z^2 > 0 on [0, 1])'
            )
    return checked


def config_path(filename):
    """Return the path of a file shipped in config/ (shipped_file), or raise ParameterError."""
    return shipped_file('config', filename)


def shipped_file(folder, filename):
    """
    Return the path of a file shipped in folder/ (config, foxglove), or raise ParameterError.

    Looked for, in this order: the package's share directory as ament_index knows it
    (a colcon install, once its setup file is sourced: AMENT_PREFIX_PATH); the
    share directory of the prefix this module is installed in (a colcon or pip
    install used without sourcing); the source tree (a clone, or an editable install).
    The error names every place it looked.
    """
    candidates = []
    try:
        from ament_index_python.packages import get_package_share_directory

        candidates.append(Path(get_package_share_directory(PACKAGE)) / folder / filename)
    except (ImportError, LookupError, OSError, ValueError):
        pass  # no ament_index, no AMENT_PREFIX_PATH, or valve_sim not in it: the fallbacks
    here = Path(__file__).resolve()
    candidates += [
        here.parents[min(5, len(here.parents) - 1)] / 'share' / PACKAGE / folder / filename,
        Path(sys.prefix) / 'share' / PACKAGE / folder / filename,
        here.parents[2] / folder / filename,  # source tree
    ]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise ParameterError(
        f"{folder} file '{filename}' not found in: {', '.join(str(c) for c in candidates)}"
    )


def parameter_document(path):
    """
    Return the parsed YAML of a ROS 2 parameter file, or raise ParameterError.

    The file is read once, within the limits of input_files.PARAMETER_FILE (a regular
    file, bounded size, aliases and nesting, numbers that fit a float), and parsed as
    ROS 2 reads it (YAML 1.2 floats: 1e-3 is a float).
    """
    try:
        return read_yaml(path, PARAMETER_FILE)
    except InputFileError as error:
        raise ParameterError(str(error)) from None


def read_parameter_file(path, namespace=''):
    """
    Read what a ROS 2 parameter file sets for valve_node in namespace ('' is the root).

    Every section that rcl would apply to the node (valve_sim.core.parameter_sections:
    '/**', '/**/relief_valve', '/<namespace>/relief_valve', and 'relief_valve' in the
    root namespace) is merged in rcl's order; returns {dotted name: value}, values
    unvalidated. Raises ParameterError if the file cannot be read or no section applies
    (naming the sections meant for the node that apply elsewhere).
    """
    fqn = node_fqn(namespace, NODE_NAME)
    try:
        sections = parameters_for_node([(str(path), parameter_document(path))], fqn)
    except SectionError as error:
        raise ParameterError(f'parameter file {error}') from None
    if not sections.applied:
        raise ParameterError(
            f'parameter file {path} has no section that applies to {fqn} '
            f"('/**/{NODE_NAME}: ros__parameters:' applies in any namespace)"
            + (f'; {describe_not_applied(sections, fqn)}' if sections.not_applied else '')
        )
    return sections.parameters


# Parameters of fault injection (valve_sim.core.faults, valve_sim.core.sensors): prefixes
# and the schedule file; load_parameters() hands them on unchecked.
INJECTION_PREFIXES = ('fault.', 'sensor.')
FAULT_SCHEDULE = 'fault_schedule'


def load_parameters(path=None, overrides=None, injection=None, namespace=''):
    """
    Load validated model parameters: config/reference.yaml, overlaid by a parameter file.

    path: a ROS 2 parameter file that sets some or all parameters (like a second
    --params-file for the node), its sections applied as they apply to valve_node in
    namespace (read_parameter_file); the rest keep their reference values. Run-time
    settings in either file (SETTINGS: step_size, publish_rate, ...) are checked
    and returned separately; a retired parameter (RETIRED) in the file is ignored with a
    logged warning; any other key is an error. overrides (name or paper
    symbol -> value) are applied last. Fault and sensor settings (fault.*, sensor.*,
    fault_schedule) go into the dict injection, unchecked; without one they are an
    error (the command does not use them). Returns (params, settings).
    """
    raw = read_parameter_file(config_path('reference.yaml'))
    if path is not None:
        raw.update(without_retired(read_parameter_file(path, namespace), path))
    raw.update(overrides or {})
    for name in [n for n in raw if n.startswith(INJECTION_PREFIXES) or n == FAULT_SCHEDULE]:
        if injection is None:
            raise ParameterError(
                f"'{name}': fault and sensor settings are used by valve_node and "
                '`valve-sim simulate` only'
            )
        injection[name] = raw.pop(name)
    settings = {
        name: check_value(name, raw.pop(name))
        for name in list(raw)
        if name in SETTING_SPECS or name == PRESET_PRESSURE.name
    }
    params = {resolve_name(name): value for name, value in raw.items()}
    return validate(params), settings


def scaled(params, changes):
    """
    Copy of params with each named parameter multiplied by (1 + percent/100), validated.

    changes: {name or symbol: percent}. Used for the paper's parameter study and Table 2.
    """
    new = dict(params)
    for name, percent in changes.items():
        name = resolve_name(name)
        new[name] = params[name] * (1.0 + percent / 100.0)
    return validate(new)
