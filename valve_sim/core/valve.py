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
A valve as a library user holds it: validated, immutable Parameters and its operating point.

Parameters wraps core.parameters' one loader and one validation (load_parameters,
validate): it is checked when it is built, never changes, and replace() gives a checked
variant. It is a read-only Mapping {name: value [SI]}, so every function of the library
that takes a parameter dict takes it too. operating_point() is the exact steady state at
one inlet flow (Eqs. 1-16 balanced, core.steady_state) with its linear modes (core.linear).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
import os
from types import MappingProxyType
from typing import TYPE_CHECKING, Union

from valve_sim.core.parameters import load_parameters, resolve_name, SPECS, validate

if TYPE_CHECKING:
    from valve_sim.core.linear import Mode


PathLike = Union[str, 'os.PathLike[str]']


class Parameters(Mapping[str, float]):
    """
    The model parameters of one valve (Table 1), SI, validated when built, immutable.

    Parameters() is the catalogue's reference valve (config/reference.yaml);
    Parameters.load(path) overlays a ROS 2 parameter file; Parameters(values) checks a
    complete {name: value} dict. Names are ROS names or paper symbols ('d_c').
    Raises ParameterError (what is wrong, the limit) from any of them.
    """

    __slots__ = ('_values',)
    _values: MappingProxyType[str, float]

    def __init__(self, values: Mapping[str, float] | None = None, **changes: float) -> None:
        base = load_parameters().params if values is None else dict(values)
        base.update({resolve_name(name): value for name, value in changes.items()})
        self._values = MappingProxyType(validate(base))

    @classmethod
    def load(cls, path: PathLike | None = None, namespace: str = '',
             **changes: float) -> Parameters:
        """Return the reference valve overlaid by the parameter file at path, then changes."""
        return cls(load_parameters(path, changes, namespace).params)

    def replace(self, **changes: float) -> Parameters:
        """Return a validated copy with the named parameters (names or symbols) changed."""
        return Parameters(self._values, **changes)

    def scaled(self, **percent: float) -> Parameters:
        """Return a validated copy with each named parameter changed by percent [%]."""
        return self.replace(**{
            name: self[resolve_name(name)] * (1.0 + change / 100.0)
            for name, change in percent.items()
        })

    def as_dict(self) -> dict[str, float]:
        """Return a plain, mutable {name: value [SI]} copy."""
        return dict(self._values)

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Mapping) and dict(self._values) == dict(other)

    def __hash__(self) -> int:
        return hash(tuple(self._values.items()))

    def __repr__(self) -> str:
        reference = load_parameters().params
        changed = {name: v for name, v in self._values.items() if v != reference[name]}
        return f'Parameters({changed!r})' if changed else 'Parameters()  # the reference valve'


@dataclass(frozen=True)
class OperatingPoint:
    """
    The valve's exact steady state at one inlet flow, and its linear modes there.

    inlet_flow [m^3/s]; tank_pressure [Pa, gauge]; state: {state name: value} (pressures
    [Pa, gauge], positions [m], velocities [m/s]) as core.model.STATE_NAMES; modes:
    core.linear.Mode, slowest first. status 0 and message 'found' as scipy's results:
    a point that cannot be found raises SteadyStateError instead.
    """

    inlet_flow: float
    tank_pressure: float
    state: dict[str, float]
    modes: list[Mode]
    status: int = 0
    message: str = 'found'

    @property
    def supply_pressure(self) -> float:
        """p_s [Pa, gauge]."""
        return self.state['supply_pressure']


def operating_point(params: Mapping[str, float], inlet_flow: float,
                    tank_pressure: float = 0.0) -> OperatingPoint:
    """
    Return the OperatingPoint at inlet_flow [m^3/s] and tank_pressure [Pa, gauge].

    Raises ParameterError for invalid params, SteadyStateError where there is none.
    """
    from valve_sim.core.linear import modes
    from valve_sim.core.model import STATE_NAMES
    from valve_sim.core.steady_state import steady_state

    params = validate(params)
    state = steady_state(params, inlet_flow, tank_pressure=tank_pressure, stable=False)
    return OperatingPoint(
        float(inlet_flow), float(tank_pressure),
        {name: float(value) for name, value in zip(STATE_NAMES, state)},
        modes(params, inlet_flow, tank_pressure),
    )


__all__ = ['OperatingPoint', 'operating_point', 'Parameters', 'SPECS']
