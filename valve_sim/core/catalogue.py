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
The parameter catalogue: every parameter of valve_node and analyser_node, once.

Each entry (ParameterSpec) says what a parameter is: its ROS name, the paper's symbol,
SI unit, inclusive limits, meaning and source, its default, its kind (double, bool,
integer, string), its section and whether valve_node retunes it live. Everything else
comes from here: the specs of parameters.py, faults.py and sensors.py, the nodes'
ROS declarations (valve_sim.ros.ros_parameters), validation, the --help texts, the
CLI's --set and the parameter-file loader (split() says which part of the valve a
name sets), and test_parameter_docs.py holds the docs' parameter tables against it.

Sections:
  model     the valve model (Table 1 and our geometry); default: config/reference.yaml
  setting   run-time settings in the same files; default: config/reference.yaml
  preset    preset_pressure, the adjusting screw; default: the cracking pressure
  fault     fault.*: valve faults (docs/faults.md)
  sensor    sensor.<topic>.<setting>, sensor.noise_seed: the pressure transducers
  schedule  fault_schedule, a fault scenario file
  analyser  analyser_node's own doubles (read-only); it also takes ambient_pressure

Light on purpose (standard library only): the commands' --help reads it. Long on purpose
(over 600 lines): it is a table, one entry per parameter, and no logic but split().
"""

from dataclasses import dataclass, field, replace


@dataclass(frozen=True)
class ParameterSpec:
    """
    One parameter: the catalogue's entry.

    name: the ROS parameter name; symbol: the paper's symbol; unit: SI unit ('1':
    dimensionless, 'bool' for a switch); minimum/maximum: inclusive limits (None for a
    switch or a file name); description: its meaning; source: where the value comes
    from; default: its value when nothing sets it (None: config/reference.yaml, or
    computed, see the section); section: see the module; kind: 'double', 'bool',
    'integer' or 'string'; live: valve_node retunes it between ticks (else read-only).
    """

    name: str
    symbol: str
    unit: str
    minimum: float
    maximum: float
    description: str
    source: str
    default: object = None
    section: str = 'model'
    kind: str = 'double'
    live: bool = True

    def describe(self):
        if self.kind == 'bool':
            return f'{self.description} [bool]'
        return f'{self.description} ({self.symbol}) [{self.unit}]'


TABLE1 = 'paper, Table 1'
OURS = 'our choice, see docs/model.md'
FAULTS = 'our fault model, see docs/faults.md'
SENSORS = 'our transducer model, see docs/faults.md'
ANALYSER = 'valve_sim analyser_node'

# [Pa] the ambient (atmospheric) absolute pressure by default: the ambient_pressure of
# config/reference.yaml, the zero of the model's gauge pressures, and the default of every
# reader and writer of absolute pressures on the wire.
STANDARD_ATMOSPHERE = 101325.0


MODEL = (
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
        section='setting',
    ),
    ParameterSpec(
        'publish_rate', 'f_pub', 'Hz', 1.0, 1e4, 'valve_node tick and publish rate', OURS,
        section='setting',
    ),
    ParameterSpec(
        'initial_inlet_flow',
        'q_in,0',
        'm^3/s',
        0.0,
        0.01,
        'inlet flow whose exact steady state the node starts from',
        'paper, Conditions for Calculation (5 L/min)',
        section='setting',
        live=False,
    ),
    ParameterSpec(
        'input_timeout',
        't_timeout',
        's',
        0.0,
        3600.0,
        'inlet_flow silence after which the node reports stale input (0 disables)',
        OURS,
        section='setting',
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
        section='setting',
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
        section='setting',
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
    section='preset',
)

FAULT_PREFIX = 'fault.'


def _fault(name, symbol, unit, maximum, description):
    return ParameterSpec(FAULT_PREFIX + name, symbol, unit, 0.0, maximum, description, FAULTS,
                         default=0.0, section='fault')


def _fault_switch(name, description):
    return ParameterSpec(FAULT_PREFIX + name, '', 'bool', None, None, description, FAULTS,
                         default=False, section='fault', kind='bool')


FAULT_SPECS = (
    _fault('bearing_coulomb_friction', 'F_c', 'N', 1000.0,
           'Coulomb (sliding) friction on the main valve from contaminated hydrostatic '
           'bearings'),
    _fault('bearing_static_friction', 'F_st', 'N', 1000.0,
           'static friction (stiction) on the main valve at rest; taken as at least F_c'),
    _fault('damping_orifice_blockage', 'b_c', '1', 1.0,
           "fraction of the damping orifice's flow area lost (1: fully blocked)"),
    _fault('bearing_orifice_blockage', 'b_b', '1', 1.0,
           "fraction of the hydrostatic bearing orifices' flow area lost (1: fully blocked)"),
    _fault('pilot_spring_weakening', 'w_p', '1', 1.0,
           "fraction of the pilot spring's stiffness k_p lost (preload position y_0 kept)"),
    _fault('seat_leakage_diameter', 'd_l', 'm', 0.005,
           'worn main seat / internal leakage: equivalent orifice diameter from supply to tank '
           '(discharge coefficient C_d)'),
    _fault_switch('pilot_spring_broken', 'broken pilot spring: no stiffness and no preload force'),
    _fault_switch('main_valve_stuck',
                  'main valve stuck: x frozen at its position when the fault is set'),
)

SENSOR_PREFIX = 'sensor.'
# The published pressures, each behind a transducer (core.model's STATE_NAMES p_s .. p_c).
SENSOR_TOPICS = (
    'supply_pressure', 'intermediate_pressure', 'pilot_pressure', 'poppet_chamber_pressure'
)


def _sensor(name, symbol, unit, minimum, maximum, description, default=0.0):
    return ParameterSpec(name, symbol, unit, minimum, maximum, description, SENSORS,
                         default=default, section='sensor')


def _sensor_switch(name, description):
    return ParameterSpec(name, '', 'bool', None, None, description, SENSORS, default=False,
                         section='sensor', kind='bool')


# The settings of one transducer, named without 'sensor.<topic>.'; the order is that of
# the columns of sensors.sense.
SENSOR_SETTINGS = (
    _sensor('bandwidth', 'f_c', 'Hz', 0.0, 1e6, 'first-order lag bandwidth; 0: no lag'),
    _sensor('bias', 'b', 'Pa', -1e8, 1e8, 'offset added to the reading'),
    _sensor('noise_std', 'sigma', 'Pa', 0.0, 1e8, 'standard deviation of Gaussian noise'),
    _sensor('resolution', 'q', 'Pa', 0.0, 1e8,
            'quantisation step of the reading; 0: none, else at least 1e-3 Pa'),
    _sensor('range_min', 'p_min', 'Pa', 0.0, 1e9,
            'lower end of the measuring range (absolute): the reading saturates there'),
    _sensor('range_max', 'p_max', 'Pa', 0.0, 1e9,
            'upper end of the measuring range (absolute): the reading saturates there; 0: none'),
    _sensor('stuck_at', 'p_stuck', 'Pa', -1.0, 1e9,
            'reading of a stuck sensor (absolute); negative: the last reading before it stuck',
            default=-1.0),
    _sensor_switch('stuck', 'sensor fault: the reading frozen (at stuck_at)'),
    _sensor_switch('dropout', 'sensor fault: nothing published on this topic'),
)
NOISE_SEED = ParameterSpec(
    SENSOR_PREFIX + 'noise_seed', 'seed', '1', 0, 2**31 - 1,
    'seed of the sensor noise (one stream per topic): the same seed repeats a run', SENSORS,
    default=0, section='sensor', kind='integer',
)


def _per_topic(setting, topic):
    return replace(setting, name=f'{SENSOR_PREFIX}{topic}.{setting.name}',
                   description=f'{topic} sensor: {setting.description}')


SENSOR_SPECS = tuple(
    _per_topic(setting, topic) for topic in SENSOR_TOPICS for setting in SENSOR_SETTINGS
) + (NOISE_SEED,)

FAULT_SCHEDULE_SPEC = ParameterSpec(
    'fault_schedule', '', 'file', None, None,
    'fault scenario file (YAML, docs/faults.md): events at t [s] from the first '
    "tick on the node's clock (from the next tick when set live); '' for none",
    FAULTS, default='', section='schedule', kind='string',
)


def _analyser(name, symbol, unit, minimum, maximum, default, description):
    return ParameterSpec(name, symbol, unit, minimum, maximum, description, ANALYSER,
                         default=default, section='analyser', live=False)


ANALYSER_SPECS = (
    _analyser('step_threshold', 'dq_step', 'm^3/s', 0.0, 1.0, 1e-6,
              'smallest change of the applied inlet flow taken as a step'),
    _analyser('step_merge_time', 't_merge', 's', 0.0, 10.0, 0.05,
              'changes this soon after a step belong to it (a ramp, a noisy edge)'),
    _analyser('drain_period', 't_drain', 's', 1e-3, 0.1, 0.005,
              'period of taking the queued messages, writing and analysing them'),
    _analyser('flush_interval', 't_flush', 's', 0.05, 60.0, 1.0,
              'longest time recorded data waits before its chunk is handed to the operating '
              'system'),
    _analyser('status_period', 't_status', 's', 0.01, 60.0, 1.0,
              'period of the recording status on /diagnostics (a lockstep run waits on it)'),
)

CATALOGUE = {
    spec.name: spec
    for spec in MODEL + SETTINGS + (PRESET_PRESSURE,) + FAULT_SPECS + SENSOR_SPECS
    + (FAULT_SCHEDULE_SPEC,) + ANALYSER_SPECS
}


def section(name):
    """Return the entries of the section name, in catalogue order, as {name: spec}."""
    return {spec.name: spec for spec in CATALOGUE.values() if spec.section == name}


# The doubles analyser_node declares (read-only), with their defaults: the ambient pressure
# it subtracts is the standard atmosphere unless set.
ANALYSER_DOUBLES = (replace(CATALOGUE['ambient_pressure'], default=STANDARD_ATMOSPHERE,
                            live=False),) + ANALYSER_SPECS
# valve_node's parameters of the catalogue; those it retunes between ticks.
VALVE_NODE_SPECS = {name: spec for name, spec in CATALOGUE.items() if spec.section != 'analyser'}
LIVE_NAMES = frozenset(name for name, spec in VALVE_NODE_SPECS.items() if spec.live)
INJECTION_SECTIONS = ('fault', 'sensor', 'schedule')


def section_of(name):
    """
    Return the section a ROS parameter name belongs to, or None (unknown, or a symbol).

    An unknown fault.* or sensor.* name is still a fault or sensor setting: their own
    checks name it and list the known ones.
    """
    if name in CATALOGUE:
        return CATALOGUE[name].section
    if name.startswith(FAULT_PREFIX):
        return 'fault'
    if name.startswith(SENSOR_PREFIX):
        return 'sensor'
    return None


@dataclass
class Change:
    """
    A change {name: value} split by what it sets, each part in the change's order.

    other: names of no section (paper symbols, retired or unknown names), for the
    caller to resolve or refuse.
    """

    model: dict = field(default_factory=dict)
    setting: dict = field(default_factory=dict)
    preset: dict = field(default_factory=dict)
    fault: dict = field(default_factory=dict)
    sensor: dict = field(default_factory=dict)
    schedule: dict = field(default_factory=dict)
    analyser: dict = field(default_factory=dict)
    other: dict = field(default_factory=dict)

    @property
    def injection(self):
        """Return the fault, sensor and schedule parts as one {name: value}, in order."""
        return {**self.fault, **self.sensor, **self.schedule}


def split(changes):
    """Split a change {name: value} into its parts (Change) by the catalogue's sections."""
    parts = Change()
    for name, value in changes.items():
        getattr(parts, section_of(name) or 'other')[name] = value
    return parts
