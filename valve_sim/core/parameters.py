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
Model parameters: validation and parameter files.

Every parameter has one entry in the catalogue (valve_sim.core.catalogue); PARAMETERS
are its model section, SETTINGS its run-time settings. The values themselves live in
config/reference.yaml (ROS 2 parameter-file format), so the command line and the ROS
node read the same numbers. All values are SI.

No ROS imports here: the node turns these specs into ParameterDescriptors.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import logging
import math
import os
from pathlib import Path
import sys
from typing import Any, Optional, Union

import numpy as np
# STANDARD_ATMOSPHERE: the readers and writers of the wire import it from here.
from valve_sim.core.catalogue import (  # noqa: F401
    FAULT_SCHEDULE_SPEC,
    MODEL as PARAMETERS,
    PRESET_PRESSURE,
    SETTINGS,
    split,
    STANDARD_ATMOSPHERE,
)
from valve_sim.core.errors import InputFileError, ParameterError, SectionError
from valve_sim.core.input_documents import read_yaml
from valve_sim.core.input_files import PARAMETER_FILE, shown
from valve_sim.core.parameter_sections import describe_not_applied, node_fqn, parameters_for_node


PACKAGE = 'valve_sim'
NODE_NAME = 'relief_valve'


SPECS = {spec.name: spec for spec in PARAMETERS}
BEARING_GRID = np.linspace(0.0, 1.0, 101)  # z = 1 - p_p/p_s where Eq. (12) must rise
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


def resolve_name(name: str) -> str:
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
    return checked_number(spec, value)


def unit_suffix(spec):
    """Return ' ' + the unit of spec to write after a number, or '' for a fraction ('1')."""
    return '' if spec.unit == '1' else f' {spec.unit}'


def checked_number(spec, value, kind='parameter'):
    """
    Return value as a float if it is a finite number within spec's limits.

    Raise ParameterError naming the parameter (kind, spec.name), its symbol and limits.
    """
    if type(value) is float and spec.minimum <= value <= spec.maximum and math.isfinite(value):
        return value  # the common case, before any message is built (simulate validates)
    label = f"{kind} '{spec.name}' ({spec.symbol})"
    unit = unit_suffix(spec)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParameterError(
            f'{label} must be a number{unit and " in" + unit}, got {shown(value)}'
        )
    if isinstance(value, int) and abs(value) > sys.float_info.max:
        value = math.inf  # an integer no float holds; a NaN stays nan, reported as given
    value = float(value)
    if not math.isfinite(value):
        raise ParameterError(f'{label} must be finite, got {value}')
    if not spec.minimum <= value <= spec.maximum:
        raise ParameterError(
            f'{label} = {value:g}{unit} is outside its limits '
            f'[{spec.minimum:g}, {spec.maximum:g}]{unit}'
        )
    return value


def checked_switch(name, value, kind='parameter'):
    """Return value if it is a bool; raise ParameterError naming the switch (kind, name)."""
    if not isinstance(value, bool):
        raise ParameterError(f"{kind} '{name}' must be true or false, got {shown(value)}")
    return value


def validate(params: Mapping[str, Any]) -> dict[str, float]:
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
    falling = np.flatnonzero(k1 + 2.0 * k2 * BEARING_GRID + 3.0 * k3 * BEARING_GRID**2 <= 0.0)
    if len(falling):  # one expression over the grid: simulate() validates at every call
        raise ParameterError(
            f'bearing coefficients K_1..K_3 = {k1:g}, {k2:g}, {k3:g} give a bearing flow '
            f'that does not rise with the pressure drop at 1 - p_p/p_s = '
            f'{BEARING_GRID[falling[0]]:.2f} '
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


FAULT_SCHEDULE = FAULT_SCHEDULE_SPEC.name


@dataclass
class LoadedParameters:
    """
    What load_parameters read.

    params: the model parameters, validated; settings: run-time settings and
    preset_pressure, checked; injection: fault.*, sensor.* and fault_schedule, unchecked.
    """

    params: dict[str, float]
    settings: dict[str, float]
    injection: dict[str, Any] = field(default_factory=dict)


def load_parameters(
    path: Union[str, os.PathLike[str], None] = None,
    overrides: Optional[Mapping[str, Any]] = None, namespace: str = '',
    with_injection: bool = False,
) -> LoadedParameters:
    """
    Load validated model parameters: config/reference.yaml, overlaid by a parameter file.

    path: a ROS 2 parameter file that sets some or all parameters (like a second
    --params-file for the node), its sections applied as they apply to valve_node in
    namespace (read_parameter_file); the rest keep their reference values. Run-time
    settings in either file (SETTINGS: step_size, publish_rate, ...) are checked
    and returned separately; a retired parameter (RETIRED) in the file is ignored with a
    logged warning; any other key is an error. overrides (name or paper
    symbol -> value) are applied last. Fault and sensor settings (fault.*, sensor.*,
    fault_schedule) are returned unchecked with with_injection, else they are an
    error (the command does not use them). Returns LoadedParameters.
    """
    raw = read_parameter_file(config_path('reference.yaml'))
    if path is not None:
        raw.update(without_retired(read_parameter_file(path, namespace), path))
    raw.update(overrides or {})
    change = split(raw)
    injection = {name: value for name, value in raw.items() if name in change.injection}
    if injection and not with_injection:
        raise ParameterError(
            f"'{next(iter(injection))}': fault and sensor settings are used by valve_node and "
            '`valve-sim simulate` only'
        )
    settings = {
        name: check_value(name, value)
        for name, value in raw.items()
        if name in change.setting or name in change.preset
    }
    params = {
        resolve_name(name): value
        for name, value in raw.items()
        if name not in injection and name not in settings
    }
    return LoadedParameters(validate(params), settings, injection)


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
