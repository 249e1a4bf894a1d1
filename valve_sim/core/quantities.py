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
Physical quantities written in a file: a number in SI units, or a number and a unit.

    5 L/min   20L/min   8.33e-5   7 MPa   70 bar   0.25   250 ms

A bench scenario (valve_sim.analysis.scenarios.bench_scenario) writes its flows, pressures and
times so. Each dimension has its table of units (factor to SI); a bare number is SI.
Pressures here are the model's gauge pressures [Pa] (docs/model.md).
"""

import math
import re

from valve_sim.core.errors import ParameterError
from valve_sim.core.flow_step import LITRE_PER_MINUTE


FLOW = ('flow', 'm^3/s', {'m^3/s': 1.0, 'm3/s': 1.0, 'L/min': LITRE_PER_MINUTE,
                          'l/min': LITRE_PER_MINUTE})
PRESSURE = ('pressure', 'Pa', {'Pa': 1.0, 'kPa': 1e3, 'MPa': 1e6, 'bar': 1e5})
TIME = ('time', 's', {'s': 1.0, 'ms': 1e-3})
LENGTH = ('length', 'm', {'m': 1.0, 'mm': 1e-3, 'um': 1e-6})
VELOCITY = ('velocity', 'm/s', {'m/s': 1.0, 'mm/s': 1e-3})
FREQUENCY = ('frequency', 'Hz', {'Hz': 1.0})
NUMBER = ('number', '', {})
_WRITTEN = re.compile(r'^\s*([-+0-9.eE]+)\s*(\S*)\s*$')


def parse_quantity(value, dimension):
    """
    Return value in SI units: a number (SI) or a text 'number unit' of dimension's table.

    dimension: (name, SI unit, {unit: factor to SI}), e.g. FLOW. Raises ParameterError
    (a ValueError) with what was expected; the value must be finite.
    """
    name, unit, units = dimension
    example = f'e.g. 5 {next(iter(units))}' if units else 'a number'
    if isinstance(value, bool):
        raise ParameterError(f'expected a {name}, got {value!r} ({example})')
    if isinstance(value, (int, float)):
        number = float(value)
    elif isinstance(value, str) and _WRITTEN.match(value):
        text, written = _WRITTEN.match(value).groups()
        if written and written not in units:
            raise ParameterError(
                f'{value!r}: unknown {name} unit {written!r} '
                f'(units: {", ".join(units) or "none, a plain number"})'
            )
        try:
            number = float(text) * units.get(written, 1.0)
        except ValueError:
            raise ParameterError(f'expected a {name}, got {value!r} ({example})') from None
    else:
        raise ParameterError(f'expected a {name}, got {value!r} ({example})')
    if not math.isfinite(number):
        raise ParameterError(f'{name} must be finite, got {value!r}')
    return number


# How a value of each dimension is shown to a person: unit and its factor to SI.
DISPLAY = {'flow': ('L/min', LITRE_PER_MINUTE), 'pressure': ('MPa', 1e6), 'length': ('mm', 1e-3),
           'velocity': ('mm/s', 1e-3)}


def with_unit(value, dimension):
    """Return an SI value as text in the dimension's display unit (6 significant digits)."""
    unit, factor = DISPLAY.get(dimension[0], (dimension[1], 1.0))
    return f'{value / factor:.6g} {unit}'.rstrip()
