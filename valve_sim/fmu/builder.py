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
into it as resources/parameters.yaml, a ROS 2 parameter file (parameter_file()). Its
binary is valve_sim's build of pythonfmu's export library (export_binary), in place of
the ones pythonfmu ships: binaries/linux64 only (with_binary).
"""

import io
from pathlib import Path
import tempfile
import zipfile

from valve_sim.core.errors import BuildError, ParameterError
from valve_sim.core.parameters import NODE_NAME
from valve_sim.fmu.export_binary import binary, notices


ENTRY = 'valve_sim.fmu.relief_valve_fmu'  # the module pythonfmu packs: ReliefValve


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


def build(out, params, settings, say=print):
    """
    Write the FMU to out (a path ending .fmu) with these defaults; returns its Path.

    pythonfmu builds it in a temporary folder; it is then written whole (output_files).
    say(text): progress (the binary's first compilation).
    """
    from importlib.util import find_spec

    from pythonfmu import FmuBuilder
    from valve_sim.core.output_files import replacing, write_text
    from valve_sim.fmu.relief_valve_slave import PARAMETER_FILE

    out = Path(out)
    if out.suffix != '.fmu':
        raise ParameterError(f'--out must name a .fmu file, got {out}')
    library = binary(say)  # first: a missing compiler is said before pythonfmu's work
    with tempfile.TemporaryDirectory(prefix='valve_sim_fmu_') as folder:
        defaults = Path(folder) / PARAMETER_FILE
        write_text(defaults, parameter_file(params, settings))
        built = FmuBuilder.build_FMU(
            find_spec(ENTRY).origin, dest=Path(folder) / 'build' / out.name,
            project_files=[defaults], needsExecutionTool=True,
            canHandleVariableCommunicationStepSize=True,
            canBeInstantiatedOnlyOncePerProcess=False,
        )
        with replacing(out, 'wb', explicit=True) as stream:
            stream.write(with_binary(built.read_bytes(), library.read_bytes()))
    return out


def with_binary(fmu, library):
    """
    Return the FMU's bytes with library as its only binary, binaries/linux64/<model>.so.

    pythonfmu's own binaries (linux64, win64) answer a Python exception with fmi2Fatal
    and release the instance; the slave counts on valve_sim's (fmi2Error, kept). Its
    sources' licences go with it, in documentation/licenses/.
    """
    source, packed = zipfile.ZipFile(io.BytesIO(fmu)), io.BytesIO()
    names = [n for n in source.namelist() if n.startswith('binaries/linux64/')]
    if len(names) != 1:
        raise BuildError(f'pythonfmu packed {names} as binaries/linux64: expected one .so')
    with zipfile.ZipFile(packed, 'w', zipfile.ZIP_DEFLATED) as target:
        for info in source.infolist():
            if not info.filename.startswith('binaries/'):
                target.writestr(info, source.read(info))
        target.writestr(names[0], library)
        for name, text in notices().items():
            target.writestr(name, text)
    return packed.getvalue()
