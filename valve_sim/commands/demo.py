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
The paper's step over real DDS: valve_node and analyser_node, 5 -> 20 L/min, recorded and measured.

Starts both nodes as processes (in ROS_DOMAIN_ID if set, otherwise in a domain no other
run on this machine holds, discovery kept on this machine), commands 5 L/min until the
analyser records every topic, holds it until valve_node's model time has advanced
HOLD_TIME in step with the wall clock (it compiles its kernels before it ticks, which
takes tens of seconds on a fresh clone), steps to 20 L/min, waits for the analyser's live
measures of the step, and stops both nodes with SIGINT. A step whose samples are too
sparse for its measures (valve_node fell behind real time on a busy machine) is stepped
back and tried again, up to ATTEMPTS times (valve_sim.ros.demo_driver drives it). Then it
prints the six measures beside the paper's, checks them against an offline analysis of
the bag, and draws Figure 5. The
folder gets the bag, its measures JSON, figure5.png and the two nodes' logs. Exits 1 with
one line saying what is missing if any measure, the bag or the figure is.
"""

import math
from pathlib import Path
import time

from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.commands.options import add_options
from valve_sim.core.errors import IncompleteRunError
from valve_sim.core.input_documents import read_json
from valve_sim.core.input_files import MEASURES_FILE
from valve_sim.core.output_files import make_folder


def report(folder, bag, attempts=1):
    """
    Print the live measures beside the paper's and the offline check; draw Figure 5.

    attempts: steps up commanded; each but the last was stepped back down, so the bag
    holds 2 attempts - 1 steps and the last is the one shown. Returns the JSON path.
    Raises IncompleteRunError, naming what is missing, if a measure is undefined, the
    recorded samples cannot carry them, the offline analysis disagrees (beyond
    SAME_MEASURE_TOLERANCE), or the figure was not written.
    """
    from valve_sim.analysis.recorded_steps import (
        analyse,
        measures_agree,
        plot_steps,
        sampling_problem,
        steps_text,
    )
    from valve_sim.recording.signal_reader import read_recording
    from valve_sim.ros.demo_driver import progress

    measures_path = bag.with_suffix('.measures.json')
    live = read_json(measures_path, MEASURES_FILE)['steps']
    recording = read_recording(bag)
    if len(live) != 2 * attempts - 1 or live[-1]['direction'] != 1:
        raise IncompleteRunError(
            f'the analyser measured {len(live)} steps instead of the {2 * attempts - 1} '
            f'commanded (bag {bag}, measures {measures_path})'
        )
    offline = analyse(recording)
    step = live[-1]
    print()
    if attempts > 1:
        print(
            f'the step up of attempt {attempts}: the {attempts - 1} before it could not be '
            'measured; they and their steps back down are in the bag too'
        )
    print(steps_text([step], recording, first_number=len(live), paper=True))  # the reference valve
    same = len(offline) == len(live) and all(map(measures_agree, offline, live))
    print(
        '\noffline analysis of the bag: '
        f'{"the same measures" if same else "DIFFERENT measures: " + str(offline)}'
    )
    figure = plot_steps(folder / 'figure5.png', recording, [step], first_number=len(live))[0]
    for path in (bag, measures_path, figure):
        progress(f'wrote {path}')
    undefined = {
        name: step['reasons'].get(name, 'no value')
        for name in MEASURE_NAMES
        if step[name] is None or not math.isfinite(step[name])
    }
    if undefined:
        raise IncompleteRunError(
            'measure(s) undefined: '
            + '; '.join(f'{name}: {reason}' for name, reason in undefined.items())
            + f' (logs in {folder})'
        )
    if not same:
        raise IncompleteRunError(f'the offline analysis of {bag} gives different measures')
    problem = sampling_problem(recording.time, step['t_step'], step)
    if problem:
        raise IncompleteRunError(f'the recorded step in {bag} cannot be measured: {problem}')
    if not figure.is_file() or figure.stat().st_size == 0:
        raise IncompleteRunError(f'{figure} was not written')
    return measures_path


def add_arguments(parser):
    from valve_sim.ros.live_view import add_port_option, DEFAULT_PORT, layout_path

    add_options(parser, '--out', required=False,
                help='folder for the bag, measures JSON, figure and logs (default: a new '
                'demo_<date>-<time> folder in the current directory)')
    add_port_option(parser, 'valve_node serves a live view over the Foxglove WebSocket protocol '
                    f'on this port of this machine (default {DEFAULT_PORT}; 0: any free port): '
                    f'open it in the Foxglove app with the layout {layout_path()}')


def run(args):
    from valve_sim.ros.demo_driver import drive

    folder = Path(args.out) if args.out else Path.cwd() / time.strftime('demo_%Y%m%d-%H%M%S')
    folder = make_folder(folder).resolve()
    bag, attempts = drive(folder, args.foxglove)
    report(folder, bag, attempts)
    return 0
