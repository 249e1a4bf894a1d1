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

import sys

from valve_sim.commands.options import add_options, load_from_arguments


def add_arguments(parser):
    parser.add_argument('--out', default='valve.fmu', metavar='FILE.fmu',
                        help='the FMU to write (default valve.fmu)')
    add_options(parser, '--params', '--set', '--preset-pressure', '--step-size')
    add_options(parser, '--tank-pressure', help="the tank_pressure input's start value, gauge "
                '(default: tank_pressure of the parameters, 0: ambient)')


def run(args):
    from valve_sim.core.extras import require

    require('building an FMU', 'fmu', 'pythonfmu')
    from valve_sim.fmu.builder import build

    loaded = load_from_arguments(args)
    params, settings = loaded.params, loaded.settings
    path = build(args.out, params, settings,
                 say=lambda text: print(f'valve-sim fmu: {text}', file=sys.stderr, flush=True))
    print(f'wrote {path}: FMI 2.0 co-simulation, model ReliefValve; it needs Python with '
          'valve_sim installed where it runs (docs/fmu.md)', file=sys.stderr)
    return 0
