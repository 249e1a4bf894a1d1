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
Global sensitivity of the six measures: Sobol first-order and total indices (SALib).

By default the paper's six parameters (m_m, m_p, V_p, V_c, d_c, k_p) vary together,
each uniform on +-20 % (the paper's one-at-a-time range); --vary takes the forms of
`tolerance`. --samples N base samples give N (D + 2) runs of the paper's step
test, each valve set to the preset first (protocol held-preset, or
--frozen-preload). Writes into --out:
  results.jsonl        one row per run as it completes (--resume)
  samples.csv          the design: index, parameters, preload, measures, pass (= the
                       run succeeded), reasons, error (as tolerance's samples.csv)
  indices.csv          measure, parameter, S1, S1_conf, ST, ST_conf, interaction
                       (ST - S1); conf: half-width of the 95 % bootstrap interval
  design.json          the design: distributions, protocol, failed runs, and per
                       measure why runs have no value (undefined_reasons)
  sobol_<measure>.png  S1 and ST bars with their intervals, one chart per measure
"""

import csv
from pathlib import Path
import sys

from valve_sim.analysis.paper import STUDY_PARAMETERS
from valve_sim.analysis.steps.measures import MEASURE_NAMES
from valve_sim.analysis.studies.backend import check_runs
from valve_sim.analysis.studies.cases import preset_protocol, run_samples
from valve_sim.analysis.studies.sensitivity import sobol_design, sobol_indices
from valve_sim.analysis.studies.tolerances import (
    parse_variations, undefined_reasons, write_samples,
)
from valve_sim.commands.options import (
    add_protocol_arguments,
    add_runner_arguments,
    add_study_arguments,
    load_from_arguments,
)
from valve_sim.core.errors import StudyError
from valve_sim.core.extras import require
from valve_sim.core.output_files import json_text, make_folder, replacing, write_text
from valve_sim.core.parameters import SPECS


PAPER_RANGES = ','.join(f'{symbol}=±20%' for symbol in STUDY_PARAMETERS)


def add_arguments(parser):
    add_study_arguments(parser, 'base samples N, a power of two: N (D + 2) runs for D '
                        'parameters (default 256)')
    parser.add_argument('--vary', action='append', metavar='NAME=SPEC,...',
                        help='parameters and distributions as for tolerance (default: '
                        + PAPER_RANGES.replace('%', '%%') + ')')
    add_protocol_arguments(parser)
    add_runner_arguments(parser)


def measure_indices(distributions, rows, seed):
    """{measure: indices dict, or the reason they are undefined (str)}."""
    result = {}
    for name in MEASURE_NAMES:
        outputs = [
            float('nan') if row['measures'][name] is None else row['measures'][name]
            for row in rows
        ]
        try:
            result[name] = sobol_indices(distributions, outputs, seed)
        except ValueError as error:
            reasons = undefined_reasons(rows, name)
            common = f' (most often: {next(iter(reasons))})' if reasons else ''
            result[name] = f'indices undefined: {error}{common}'
    return result


def write_indices(path, distributions, indices):
    with replacing(path, 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(
            ['measure', 'parameter', 'symbol', 'S1', 'S1_conf', 'ST', 'ST_conf', 'interaction']
        )
        for name, entry in indices.items():
            if isinstance(entry, str):
                continue
            for i, distribution in enumerate(distributions):
                writer.writerow(
                    [
                        name,
                        distribution.name,
                        SPECS[distribution.name].symbol,
                        *(float(entry[key][i]) for key in ('S1', 'S1_conf', 'ST', 'ST_conf')),
                        float(entry['ST'][i] - entry['S1'][i]),
                    ]
                )


def print_indices(distributions, indices):
    symbols = [SPECS[d.name].symbol for d in distributions]
    print(f'{"measure":<14}{"index":<6}' + ''.join(f'{s:>14}' for s in symbols))
    for name, entry in indices.items():
        if isinstance(entry, str):
            print(f'{name:<14}{entry}')
            continue
        for key in ('S1', 'ST'):
            cells = ''.join(
                f'{entry[key][i]:>7.3f} ±{entry[key + "_conf"][i]:<5.3f}'
                for i in range(len(symbols))
            )
            print(f'{name if key == "S1" else "":<14}{key:<6}{cells}')


def run(args):
    require('sensitivity', 'studies', 'SALib', error=StudyError)
    loaded = load_from_arguments(args)
    params, settings = loaded.params, loaded.settings
    distributions = parse_variations(args.vary or [PAPER_RANGES], params)
    preset, protocol = preset_protocol(args.protocol, params)
    names = [d.name for d in distributions]
    check_runs(args.samples * (len(names) + 2), f'--samples {args.samples} x ({len(names)} + 2)')
    values = sobol_design(distributions, args.samples, args.seed)
    out = make_folder(Path(args.out))
    print(
        f'sensitivity: {len(values)} runs ({args.samples} x ({len(names)} + 2)); protocol '
        f"{protocol['protocol']}: {protocol['protocol_meaning']}",
        file=sys.stderr,
    )
    rows = run_samples(
        'sensitivity', params, names, values, preset, settings['step_size'],
        out / 'results.jsonl', args.scheduler, args.workers, args.dashboard, args.resume,
        args.batch_size,
    )
    indices = measure_indices(distributions, rows, args.seed)
    write_indices(out / 'indices.csv', distributions, indices)
    write_samples(out / 'samples.csv', names, values, rows, [])
    write_text(
        out / 'design.json',
        json_text(
            {
                'base_samples': args.samples,
                'runs': len(values),
                'seed': args.seed,
                **protocol,
                'distributions': [d.describe() for d in distributions],
                'failed_runs': sum(row['error'] is not None for row in rows),
                'undefined': {n: e for n, e in indices.items() if isinstance(e, str)},
                'undefined_reasons': {
                    n: reasons for n in MEASURE_NAMES if (reasons := undefined_reasons(rows, n))
                },
            },
            indent=2,
        )
        + '\n'
    )
    from valve_sim.analysis.studies.plots import plot_sobol_indices

    labels = [SPECS[d.name].symbol for d in distributions]
    for name, entry in indices.items():
        if not isinstance(entry, str):
            plot_sobol_indices(out / f'sobol_{name}.png', name, labels, entry)
    print_indices(distributions, indices)
    print(
        f'wrote {out}/indices.csv, {out}/samples.csv, {out}/design.json and the '
        'sobol_<measure>.png charts'
    )
    return 0
