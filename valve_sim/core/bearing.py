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
Hydrostatic bearing flow of Eq. (12) and the fit of its coefficients K_1..K_3.

Each of the n bearings that carry the main valve is an orifice (diameter d_b,
discharge coefficient C_b) feeding a pocket, in series with the laminar flow
through the bearing land clearance from the pocket to the pilot chamber:

    q_1 = K_b sqrt(p_s - p_r) = G (p_r - p_p),   K_b = pi/4 C_b d_b^2 sqrt(2/rho),
    G = w c^3 / (12 mu l)   (land of width w, flow length l, radial clearance c).

With z = 1 - p_p/p_s and qhat = q_1 / (K_b sqrt(p_s)) this is
qhat^2 + lam qhat - z = 0, lam = K_b / (G sqrt(p_s)), so the total bearing flow is

    q_n = K_b sqrt(p_s) f(z),  f(z) = n (sqrt(lam^2 + 4 z) - lam) / 2.

Eq. (12) approximates f by K_1 z + K_2 z^2 + K_3 z^3; lam depends on p_s, so the
fit is made at the design pressure (the paper fits at its operating point too).
"""

import math

import numpy as np


def land_conductance(width, length, clearance, viscosity):
    """G = w c^3 / (12 mu l): laminar conductance of a bearing land [m^3/(s Pa)]."""
    return width * clearance**3 / (12.0 * viscosity * length)


def bearing_flow_function(z, lam, count):
    """f(z) of the exact series model: total bearing flow / (K_b sqrt(p_s)) [-]."""
    z = np.asarray(z, dtype=float)
    return count * (np.sqrt(lam * lam + 4.0 * z) - lam) / 2.0


def fit_bearing_coefficients(
    orifice_diameter,
    discharge_coefficient,
    density,
    conductance,
    design_pressure,
    count=4,
    z_max=1.0,
    samples=201,
):
    """
    Least-squares K_1, K_2, K_3 of Eq. (12) for the series bearing model.

    orifice_diameter d_b [m], discharge_coefficient C_b [-], density rho [kg/m^3],
    conductance G of one bearing land [m^3/(s Pa)], design_pressure p_s [Pa],
    count: number of bearings. The fit minimises the relative error over
    z = 1 - p_p/p_s in [0.01 z_max, z_max]: the flow matters in proportion to itself.
    Returns (K_1, K_2, K_3, lam, max_relative_error on [0.05 z_max, z_max]).
    """
    gain = math.pi / 4.0 * discharge_coefficient * orifice_diameter**2 * math.sqrt(2.0 / density)
    lam = gain / (conductance * math.sqrt(design_pressure))
    z = np.linspace(0.01 * z_max, z_max, samples)
    exact = bearing_flow_function(z, lam, count)
    basis = np.column_stack([z, z**2, z**3])
    k, *_ = np.linalg.lstsq(basis / exact[:, None], np.ones_like(z), rcond=None)
    relative_error = np.abs(basis @ k / exact - 1.0)
    error = float(np.max(relative_error[z >= 0.05 * z_max]))
    return float(k[0]), float(k[1]), float(k[2]), lam, error


# The bearing lands behind K_1..K_3 in config/reference.yaml (docs/model.md): four
# bearings, each an orifice of the parameter set's d_b feeding a pocket whose land
# (9 mm wide, 0.8 mm flow length, 9.5 um radial clearance) drains to the pilot chamber;
# fitted at the 7 MPa preset. tests check that the parameter file holds this fit.
REFERENCE_BEARING = {
    'count': 4,
    'land_width': 9e-3,  # w [m]
    'land_length': 0.8e-3,  # l [m]
    'clearance': 9.5e-6,  # c [m]
    'design_pressure': 7e6,  # p_s [Pa]
}
COEFFICIENTS = ('bearing_coefficient_1', 'bearing_coefficient_2', 'bearing_coefficient_3')


def reference_bearing_fit(params):
    """
    fit_bearing_coefficients() for REFERENCE_BEARING's lands and the orifice of params.

    params: a parameter dict (d_b, C_b, rho, mu are read from it).
    """
    b = REFERENCE_BEARING
    conductance = land_conductance(
        b['land_width'], b['land_length'], b['clearance'], params['fluid_viscosity']
    )
    return fit_bearing_coefficients(
        params['bearing_orifice_diameter'],
        params['bearing_discharge_coefficient'],
        params['fluid_density'],
        conductance,
        b['design_pressure'],
        b['count'],
    )


def with_bearing_fit(params):
    """Copy of params whose K_1..K_3 are the fit of REFERENCE_BEARING with its d_b."""
    return {**params, **dict(zip(COEFFICIENTS, reference_bearing_fit(params)[:3]))}
