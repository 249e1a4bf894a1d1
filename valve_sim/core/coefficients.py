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
The derived constants of the valve model: a parameter dict (and faults) -> Coefficients.

coefficients() computes the constants of Eqs. (5), (8), (9), (16) that the kernels of
valve_sim.core.model take, in SI units, from a validated parameter dict
(valve_sim.core.parameters); with_faults() changes them for a FaultSet
(valve_sim.core.faults, docs/faults.md). The Coefficients namedtuple is defined in
model.py, beside the equations that read it (numba's kernel cache records it there).
"""

import math

from valve_sim.core.catalogue import STANDARD_ATMOSPHERE
from valve_sim.core.faults import HEALTHY
from valve_sim.core.model import Coefficients, HEALTHY_TERMS, MECHANICS, VAPOUR_PRESSURE


def land_pressure_term(outer, inner):
    """(D^2 - d^2) / ln(D/d) [m^2]: the log-profile integral of a flat annular land."""
    return (outer**2 - inner**2) / math.log(outer / inner)


def coefficients(p, faults=HEALTHY, ambient_pressure=STANDARD_ATMOSPHERE):
    """
    Derive the Coefficients from a validated parameter dict and a FaultSet.

    p: see valve_sim.core.parameters; faults: valve_sim.core.faults.FaultSet;
    ambient_pressure [Pa, absolute]: the gauge pressures' zero, from which the vapour
    pressure's gauge value (cavitation_pressure) is taken.
    """
    root = math.sqrt(2.0 / p['fluid_density'])
    land_1 = land_pressure_term(
        p['first_throttle_outer_diameter'], p['first_throttle_inner_diameter']
    )
    land_2 = land_pressure_term(
        p['second_throttle_outer_diameter'], p['second_throttle_inner_diameter']
    )
    d_p, theta = p['main_valve_back_diameter'], p['poppet_half_angle']
    c_d, d_v = p['discharge_coefficient'], p['pilot_seat_diameter']
    d_s = p['sensing_rod_diameter']
    back_area = math.pi / 4.0 * d_p**2
    supply_force_area = math.pi / 4.0 * (d_p**2 - land_1 / 2.0)
    intermediate_force_area = math.pi / 8.0 * (land_1 - land_2)
    rod_area = math.pi / 4.0 * d_s**2
    poppet_chamber_area = math.pi / 4.0 * (d_v**2 - d_s**2)
    c = Coefficients(
        supply_compliance_inv=p['bulk_modulus'] / p['supply_volume'],
        intermediate_compliance_inv=p['bulk_modulus'] / p['intermediate_volume'],
        pilot_compliance_inv=p['bulk_modulus'] / p['pilot_volume'],
        poppet_chamber_compliance_inv=p['bulk_modulus'] / p['poppet_chamber_volume'],
        rod_area=rod_area,
        back_area=back_area,
        supply_force_area=supply_force_area,
        intermediate_force_area=intermediate_force_area,
        poppet_chamber_area=poppet_chamber_area,
        # Each body's areas add up to zero (a closed body): what the others leave is the tank's.
        tank_force_area=back_area - supply_force_area - intermediate_force_area,
        seat_area=rod_area + poppet_chamber_area,
        flow_force_gain=math.pi * c_d * d_v * math.sin(2.0 * theta),
        first_throttle_gain=math.pi * c_d * p['first_throttle_outer_diameter'] * root,
        second_throttle_gain=math.pi * c_d * p['second_throttle_outer_diameter'] * root,
        first_throttle_clearance=p['first_throttle_clearance'],
        bearing_gain=math.pi
        / 4.0
        * p['bearing_discharge_coefficient']
        * p['bearing_orifice_diameter'] ** 2
        * root,
        bearing_k1=p['bearing_coefficient_1'],
        bearing_k2=p['bearing_coefficient_2'],
        bearing_k3=p['bearing_coefficient_3'],
        damping_orifice_gain=math.pi / 4.0 * c_d * p['damping_orifice_diameter'] ** 2 * root,
        rod_leakage_conductance=(
            math.pi
            * d_s
            * p['sensing_rod_clearance'] ** 3
            / (12.0 * p['fluid_viscosity'] * p['sensing_rod_length'])
        ),
        poppet_gain=math.pi * c_d * d_v * math.sin(theta) * root,
        **{name: p[name] for name in MECHANICS},
        transition_pressure=p['orifice_transition_pressure'],
        burst_pressure=p['burst_pressure'],
        supply_pressure_limit=p['supply_pressure_limit'] or math.inf,
        cavitation_pressure=VAPOUR_PRESSURE - ambient_pressure,
        **HEALTHY_TERMS,
    )
    return with_faults(c, faults, p) if faults != HEALTHY else c


def with_faults(c, faults, p):
    """
    Coefficients c changed by the faults (FaultSet), p the parameter dict c came from.

    Blockage scales an orifice's flow gain with its remaining area; weakening scales
    k_p, a broken spring has k_p = 0 and no preload. The preload position y_0 (the
    adjusting screw) is never changed.
    """
    stiffness = c.pilot_spring_stiffness * (1.0 - faults.pilot_spring_weakening)
    return c._replace(
        damping_orifice_gain=c.damping_orifice_gain * (1.0 - faults.damping_orifice_blockage),
        bearing_gain=c.bearing_gain * (1.0 - faults.bearing_orifice_blockage),
        pilot_spring_stiffness=0.0 if faults.pilot_spring_broken else stiffness,
        pilot_spring_preload=0.0 if faults.pilot_spring_broken else c.pilot_spring_preload,
        coulomb_friction=faults.bearing_coulomb_friction,
        static_friction=max(faults.bearing_static_friction, faults.bearing_coulomb_friction),
        seat_leakage_gain=(
            math.pi
            / 4.0
            * p['discharge_coefficient']
            * faults.seat_leakage_diameter**2
            * math.sqrt(2.0 / p['fluid_density'])
        ),
        main_valve_free=0.0 if faults.main_valve_stuck else 1.0,
    )
