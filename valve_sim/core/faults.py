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
Valve faults: the set of injectable faults, their specs and their validation.

Each fault is a physical change of the valve (docs/faults.md):

  fault.bearing_coulomb_friction  F_c  N   contaminated hydrostatic bearings: sliding friction
  fault.bearing_static_friction   F_st N   ... and stiction (taken as at least F_c)
  fault.damping_orifice_blockage  -    1   fraction of the damping orifice's area lost (d_c)
  fault.bearing_orifice_blockage  -    1   fraction of the bearing orifices' area lost (d_b)
  fault.pilot_spring_weakening    -    1   fraction of the pilot spring's stiffness lost (k_p)
  fault.pilot_spring_broken       bool     no pilot spring stiffness and no preload force
  fault.seat_leakage_diameter     d_l  m   worn main seat: an orifice from supply to tank
  fault.main_valve_stuck          bool     the main valve frozen where it is

A fault never moves the adjusting screw: pilot_spring_preload (y_0) stays, so a weaker
spring makes a smaller preload force and a lower cracking pressure. The numbers enter the
model equations in valve_sim.core.coefficients.coefficients; all zero/false is the healthy valve.
"""

from dataclasses import dataclass, fields, replace

from valve_sim.core.catalogue import FAULT_PREFIX as PREFIX, section
from valve_sim.core.errors import ParameterError
from valve_sim.core.parameters import checked_number, checked_switch, unit_suffix


FAULT_SPECS = section('fault')  # the catalogue's fault.* entries
FAULT_DOUBLE_SPECS = {name: spec for name, spec in FAULT_SPECS.items() if spec.kind == 'double'}
FAULT_SWITCH_SPECS = {name: spec for name, spec in FAULT_SPECS.items() if spec.kind == 'bool'}
FAULT_NAMES = tuple(FAULT_DOUBLE_SPECS) + tuple(FAULT_SWITCH_SPECS)


@dataclass(frozen=True)
class FaultSet:
    """The faults in effect; field names are the parameter names without 'fault.'."""

    bearing_coulomb_friction: float = 0.0
    bearing_static_friction: float = 0.0
    damping_orifice_blockage: float = 0.0
    bearing_orifice_blockage: float = 0.0
    pilot_spring_weakening: float = 0.0
    seat_leakage_diameter: float = 0.0
    pilot_spring_broken: bool = False
    main_valve_stuck: bool = False

    def changed(self, changes):
        """
        Return a copy with changes applied; each checked.

        changes: {name: value}, names with or without 'fault.'. Raises ParameterError.
        """
        values = {}
        for name, value in changes.items():
            full = name if name.startswith(PREFIX) else PREFIX + name
            values[full[len(PREFIX):]] = check_fault(full, value)
        return replace(self, **values)

    def as_parameters(self):
        """{'fault.<name>': value} of every fault (the ROS parameters)."""
        return {PREFIX + f.name: getattr(self, f.name) for f in fields(self)}

    def active(self):
        """{'fault.<name>': value} of the faults that change the valve (non-zero, true)."""
        return {name: value for name, value in self.as_parameters().items() if value}

    def describe(self):
        """One line naming each active fault with its value and unit ('' if healthy)."""
        parts = []
        for name, value in self.active().items():
            if name in FAULT_SWITCH_SPECS:
                parts.append(name)
            else:
                parts.append(f'{name} = {value:g}{unit_suffix(FAULT_DOUBLE_SPECS[name])}')
        return ', '.join(parts)


HEALTHY = FaultSet()


def check_fault(name, value):
    """Return value checked for the fault parameter name; raise ParameterError naming it."""
    if name in FAULT_SWITCH_SPECS:
        return checked_switch(name, value, 'fault parameter')
    spec = FAULT_DOUBLE_SPECS.get(name)
    if spec is None:
        raise ParameterError(f"unknown fault '{name}'; known: {', '.join(FAULT_NAMES)}")
    return checked_number(spec, value, 'fault parameter')


# The bench supply's relief: p_s within this fraction of supply_pressure_limit is there,
# and valve_node raises its overpressure alarm (docs/faults.md).
OVERPRESSURE_MARGIN = 1e-6


def at_supply_limit(supply_pressure, limit):
    """Return whether p_s [Pa, gauge] has reached supply_pressure_limit [Pa] (0: no limit)."""
    return bool(0.0 < limit * (1.0 - OVERPRESSURE_MARGIN) <= supply_pressure)
