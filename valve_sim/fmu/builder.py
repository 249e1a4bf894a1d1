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
Build the FMU: pythonfmu packs relief_valve_slave with its parameter defaults.

build(out, params, settings) writes the .fmu (valve-sim fmu's work); the defaults go
into it as resources/parameters.yaml, a ROS 2 parameter file (parameter_file()).
"""

from pathlib import Path
import tempfile

from valve_sim.core.errors import ParameterError
from valve_sim.core.parameters import NODE_NAME


ENTRY = 'valve_sim.fmu.relief_valve_fmu'  # the module pythonfmu packs: ReliefValve
MASTER_LOGGER = 'valve_sim.fmu.master_logger'  # packed with it, in resources/


def parameter_file(params, settings):
    """Return the FMU's defaults as a ROS 2 parameter file's text (the node's own format)."""
    import yaml

    values = {**params, **{n: settings[n] for n in ('step_size', 'initial_inlet_flow',
                                                    'tank_pressure', 'ambient_pressure')}}
    document = {f'/**/{NODE_NAME}': {'ros__parameters': values}}
    return (
        '# The defaults of this FMU, written by `valve-sim fmu` (valve_sim '
        f'{__import__("valve_sim").__version__}).\n'
        + yaml.safe_dump(document, sort_keys=False)
    )


def build(out, params, settings):
    """
    Write the FMU to out (a path ending .fmu) with these defaults; returns its Path.

    pythonfmu builds it in a temporary folder; it is then written whole (output_files).
    """
    from importlib.util import find_spec

    from pythonfmu import FmuBuilder
    from valve_sim.core.output_files import replacing, write_text
    from valve_sim.fmu.relief_valve_slave import PARAMETER_FILE

    out = Path(out)
    if out.suffix != '.fmu':
        raise ParameterError(f'--out must name a .fmu file, got {out}')
    with tempfile.TemporaryDirectory(prefix='valve_sim_fmu_') as folder:
        defaults = Path(folder) / PARAMETER_FILE
        write_text(defaults, parameter_file(params, settings))
        built = FmuBuilder.build_FMU(
            find_spec(ENTRY).origin, dest=Path(folder) / 'build' / out.name,
            project_files=[defaults, find_spec(MASTER_LOGGER).origin], needsExecutionTool=True,
            canHandleVariableCommunicationStepSize=True,
            canBeInstantiatedOnlyOncePerProcess=False,
        )
        with replacing(out, 'wb', explicit=True) as stream:
            stream.write(built.read_bytes())
    return out
