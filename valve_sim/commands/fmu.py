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
Build the valve as an FMI 2.0 co-simulation FMU (pythonfmu): `valve-sim fmu --out valve.fmu`.

The FMU's slave is valve_sim.fmu.relief_valve_slave (RealTimeModel behind FMI); its
parameter defaults are config/reference.yaml overlaid by --params, --set,
--preset-pressure, --step-size and --tank-pressure, written into the FMU as
resources/parameters.yaml. The FMU runs Python: the importing machine needs Python
with valve_sim (and its dependencies) installed. docs/fmu.md says how to use it.
"""

from pathlib import Path
import sys
import tempfile

from valve_sim.commands.options import add_options, load_from_arguments
from valve_sim.core.parameters import NODE_NAME, ParameterError


SLAVE = 'valve_sim.fmu.relief_valve_slave'  # the module pythonfmu packs: ReliefValve


def add_arguments(parser):
    parser.add_argument('--out', default='valve.fmu', metavar='FILE.fmu',
                        help='the FMU to write (default valve.fmu)')
    add_options(parser, '--params', '--set', '--preset-pressure', '--step-size')
    add_options(parser, '--tank-pressure', help="the tank_pressure input's start value, gauge "
                '(default: tank_pressure of the parameters, 0: ambient)')


def parameter_file(params, settings):
    """Return the FMU's defaults as a ROS 2 parameter file's text (the node's own format)."""
    import yaml

    values = {**params, **{n: settings[n] for n in ('step_size', 'initial_inlet_flow',
                                                    'tank_pressure')}}
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
    from valve_sim.core.output_files import replacing
    from valve_sim.fmu.relief_valve_slave import PARAMETER_FILE

    out = Path(out)
    if out.suffix != '.fmu':
        raise ParameterError(f'--out must name a .fmu file, got {out}')
    with tempfile.TemporaryDirectory(prefix='valve_sim_fmu_') as folder:
        defaults = Path(folder) / PARAMETER_FILE
        defaults.write_text(parameter_file(params, settings))
        built = FmuBuilder.build_FMU(
            find_spec(SLAVE).origin, dest=Path(folder) / 'build' / out.name,
            project_files=[defaults], needsExecutionTool=True,
            canHandleVariableCommunicationStepSize=True,
            canBeInstantiatedOnlyOncePerProcess=False,
        )
        with replacing(out, 'wb', explicit=True) as stream:
            stream.write(built.read_bytes())
    return out


def run(args):
    loaded = load_from_arguments(args)
    params, settings = loaded.params, loaded.settings
    path = build(args.out, params, settings)
    print(f'wrote {path}: FMI 2.0 co-simulation, model ReliefValve; it needs Python with '
          'valve_sim installed where it runs (docs/fmu.md)', file=sys.stderr)
    return 0
