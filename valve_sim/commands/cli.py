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
The `valve-sim` command line: simulate, study, operating-point, analyse, calibrate and more.

Subcommands: simulate, study, tolerance, sensitivity, optimise, operating-point,
characteristic, analyse, calibrate, repair, fmu, demo, scenario.

Each subcommand lives in its own module with add_arguments(parser) and
run(args) -> exit code; this file only wires them together and turns the
project's errors into one clear line on stderr and exit code 1.
"""

import argparse
import importlib
import os
import re
import sys


NEGATIVE_VALUE = re.compile(r'-\.?\d')  # -5e5, -0.5bar, -.5: a value, never an option
SUBCOMMANDS = {
    'simulate': (
        'valve_sim.commands.simulate',
        'run the valve model offline for one inlet-flow step',
    ),
    'study': ('valve_sim.commands.study', "the paper's parameter study (Figures 6-13, Table 3)"),
    'tolerance': (
        'valve_sim.commands.tolerance',
        'Monte Carlo of manufacturing tolerances: yield against limits, percentiles',
    ),
    'sensitivity': (
        'valve_sim.commands.sensitivity',
        'global sensitivity: Sobol first-order and total indices (SALib)',
    ),
    'optimise': (
        'valve_sim.commands.optimise',
        'robust design optimisation: Pareto designs whose tolerance batch meets the limits',
    ),
    'operating-point': (
        'valve_sim.commands.operating_point',
        'exact steady state, flows, forces and linear modes at a flow',
    ),
    'characteristic': (
        'valve_sim.commands.characteristic',
        'static pressure-flow characteristic from a slow flow ramp up and down',
    ),
    'analyse': (
        'valve_sim.commands.analyse',
        'step measures (or --characteristic) of a recorded rosbag2 MCAP file or bag folder',
    ),
    'calibrate': (
        'valve_sim.commands.calibrate',
        "fit parameters to the paper's measures or to a recorded bag",
    ),
    'repair': (
        'valve_sim.commands.repair',
        'rewrite a truncated or crash-ended MCAP file complete (as `mcap recover`)',
    ),
    'fmu': (
        'valve_sim.commands.fmu',
        'build the valve as an FMI 2.0 co-simulation FMU (pythonfmu)',
    ),
    'demo': (
        'valve_sim.commands.demo',
        "valve_node + analyser_node over DDS: the paper's step, recorded and measured",
    ),
    'scenario': (
        'valve_sim.commands.scenario',
        'bench tests as files: run one on valve_node in lockstep and judge it (or check it)',
    ),
}


class BoundsHelpFormatter(argparse.HelpFormatter):
    """Help that states each numeric option's bounds, from its type (options.number)."""

    def _get_help_string(self, action):
        text, bounds = action.help or '', getattr(action.type, 'bounds', None)
        if not bounds or bounds in text or action.help == argparse.SUPPRESS:
            return text
        return f'{text} ({bounds})'


def build_parser(argv):
    """
    Build the parser, with the arguments of the subcommand argv names only.

    Only that subcommand's module is imported: `valve-sim --help` imports none,
    `valve-sim simulate --help` only simulate's (which keeps numba and scipy for run()).
    """
    chosen = next((argument for argument in argv if not argument.startswith('-')), None)
    parser = argparse.ArgumentParser(prog='valve-sim', description=__doc__.strip().splitlines()[0])
    commands = parser.add_subparsers(dest='command', required=True, metavar='COMMAND')
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        sub = commands.add_parser(name, help=help_text, description=help_text,
                                  formatter_class=BoundsHelpFormatter)
        if name == chosen:
            module = importlib.import_module(module_name)
            sub.description = module.__doc__.strip().splitlines()[0]
            module.add_arguments(sub)
            sub.set_defaults(run=module.run)
    return parser


def explained(error):
    """Return an error's one-line message; a file the system refused is named first."""
    if isinstance(error, OSError) and error.filename and error.strerror:
        return f'{error.filename}: {error.strerror}'
    return str(error)


def negative_values_joined(argv):
    """
    Return argv with each `--option -5e5` written `--option=-5e5`.

    argparse takes a token that starts with '-' for an option unless it is a plain
    negative number (-5, -0.5), so `--tank-pressure -5e5` or `-0.5bar` would be refused
    with "expected one argument". No option of valve-sim starts with a digit: a minus
    and a digit (or '.' and a digit) is a value.
    """
    joined = []
    for token in argv:
        option = joined[-1] if joined else ''
        if (NEGATIVE_VALUE.match(token) and option.startswith('--') and option != '--'
                and '=' not in option):
            joined[-1] = f'{option}={token}'
        else:
            joined.append(token)
    return joined


def main(argv=None):
    from valve_sim.core.errors import USER_ERRORS

    argv = negative_values_joined(sys.argv[1:] if argv is None else argv)
    args = build_parser(argv).parse_args(argv)
    try:
        return args.run(args)
    except BrokenPipeError:  # the reader went away (e.g. `| head`): stop quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except USER_ERRORS as error:
        print(f'valve-sim {args.command}: error: {explained(error)}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f'valve-sim {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
