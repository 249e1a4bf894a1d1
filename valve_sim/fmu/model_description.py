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
The slave's modelDescription.xml beyond pythonfmu's: units, ranges and initial unknowns.

Quantity: a Real with its unit, range and full-precision start; with_units_and_unknowns()
adds the UnitDefinitions (SI base units) and ModelStructure/InitialUnknowns FMI 2.0 asks for.
"""

from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Real


# The SI base-unit exponents of each unit used (FMI 2.0 UnitDefinitions).
BASE_UNITS = {
    'm': {'m': 1},
    'm^3': {'m': 3},
    'm^3/s': {'m': 3, 's': -1},
    'Pa': {'kg': 1, 'm': -1, 's': -2},
    'Pa*s': {'kg': 1, 'm': -1, 's': -1},
    'kg': {'kg': 1},
    'kg/m^3': {'kg': 1, 'm': -3},
    'N*s/m': {'kg': 1, 's': -1},
    'N/m': {'kg': 1, 's': -2},
    'rad': {'rad': 1},
    's': {'s': 1},
    '1': {},
}


class Quantity(Real):
    """A Real with its unit and range in modelDescription.xml, its start to full precision."""

    def __init__(self, name, unit, minimum=None, maximum=None, **kwargs):
        super().__init__(name, **kwargs)
        self.unit, self.minimum, self.maximum = unit, minimum, maximum

    def to_xml(self):
        element = super().to_xml()
        real = element.find('Real')
        real.set('unit', self.unit)
        if self.start is not None:
            real.set('start', repr(float(self.start)))
        for key, value in (('min', self.minimum), ('max', self.maximum)):
            if value is not None:
                real.set(key, repr(float(value)))
        return element


def parameter_description(spec):
    """Return a catalogue spec as one description line: meaning, symbol, unit and source."""
    return f'{spec.describe()}; source: {spec.source}'


def with_units_and_unknowns(root, variables):
    """
    Return pythonfmu's XML root with the units and the initial unknowns FMI 2.0 asks for.

    UnitDefinitions (after CoSimulation) with SI base units of the Quantity variables;
    the outputs, calculated at initialisation, as ModelStructure/InitialUnknowns.
    """
    structure = root.find('ModelStructure')
    initial = SubElement(structure, 'InitialUnknowns')
    for element in structure.find('Outputs'):
        SubElement(initial, 'Unknown', index=element.get('index'))
    used = sorted({v.unit for v in variables if isinstance(v, Quantity)})
    units = Element('UnitDefinitions')
    for name in used:
        unit = SubElement(units, 'Unit', name=name)
        SubElement(unit, 'BaseUnit', {k: str(v) for k, v in BASE_UNITS[name].items()})
    root.insert(list(root).index(root.find('CoSimulation')) + 1, units)
    return root
