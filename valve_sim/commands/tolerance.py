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
Monte Carlo of manufacturing tolerances: how many valves of a batch meet a spec.

Each sampled valve (--vary, see valve_sim.analysis.studies.tolerances for the forms) is
set to the preset pressure before its test, as a technician sets every valve on
the bench (protocol held-preset: the pilot spring preload re-solved so that it
cracks at the preset, the cracking pressure of the nominal valve or
--preset-pressure), or keeps the nominal preload (--frozen-preload); then the
paper's step test (5 -> 20 L/min) is run and measured. Writes into --out:
  results.jsonl   one row per run as it completes (--resume)
  samples.csv     index, the varied parameters, the preload used, the six
                  measures, pass, reasons, error (one row per sample)
  summary.json    distributions, protocol, limits, yield with its 95 % interval,
                  failures per limit, percentiles of each measure and why runs
                  have no value of it (undefined_reasons)
  measures_cdf.png, measures_vs_<parameter>.png
"""

from pathlib import Path
import sys

from valve_sim.analysis.studies.backend import check_runs
from valve_sim.analysis.studies.cases import preset_protocol, run_samples
from valve_sim.analysis.studies.tolerances import (
    draw,
    parse_limits,
    parse_variations,
    SAMPLERS,
    summarise,
    write_samples,
)
from valve_sim.commands.options import (
    add_protocol_arguments,
    add_runner_arguments,
    add_study_arguments,
    load_from_arguments,
)
from valve_sim.core.output_files import json_text, make_folder, write_text
from valve_sim.core.parameters import SPECS

# The model's modules (numba, scipy) are imported in the functions that run it, so that
# `valve-sim tolerance --help` stays quick.


def add_arguments(parser):
    add_study_arguments(parser, 'number of sampled valves (default 256)')
    parser.add_argument('--vary', action='append', required=True, metavar='NAME=SPEC,...',
                        help='parameters and their distributions: NAME=±X%% (uniform, '
                        'half-width), NAME=LO:HI (uniform), NAME=MEAN~N(S%%) or NAME=~N(S) '
                        '(normal, sigma); repeatable')
    parser.add_argument('--limits', metavar='SPEC', default='',
                        help='pass criteria, e.g. "P_1_percent<=4,T_s_ms<=600" (all must hold)')
    parser.add_argument('--sampler', choices=SAMPLERS, default='lhs',
                        help='lhs: Latin hypercube (default), sobol: scrambled Sobol (N a power '
                        'of two), random: pseudo-random (all seeded)')
    add_protocol_arguments(parser)
    add_runner_arguments(parser)


def print_summary(summary):
    result = summary['yield']
    low, high = result['ci95']
    print(
        f"yield {result['passed']}/{result['total']} = {100.0 * result['fraction']:.1f} % "
        f'(95 % interval {100.0 * low:.1f}-{100.0 * high:.1f} %) against '
        f"{', '.join(summary['limits']) or 'no limits'}"
    )
    print(f'{"measure":<14}' + ''.join(f'{"p" + str(p):>10}' for p in (1, 5, 50, 95, 99)))
    for name, entry in summary['percentiles'].items():
        if entry['defined']:
            cells = ''.join(f"{entry['p' + str(p)]:>10.4g}" for p in (1, 5, 50, 95, 99))
        else:
            cells = f'{"undefined in every run":>50}'
        note = (
            f"  ({entry['undefined']} undefined, most often: "
            f"{next(iter(entry['undefined_reasons']))})"
            if entry['undefined'] else ''
        )
        print(f'{name:<14}{cells}{note}')


def run(args):
    loaded = load_from_arguments(args)
    params, settings = loaded.params, loaded.settings
    distributions = parse_variations(args.vary, params)
    limits = parse_limits(args.limits)
    preset, protocol = preset_protocol(args.protocol, params)
    names = [d.name for d in distributions]
    check_runs(args.samples, f'--samples {args.samples}')
    values = draw(distributions, args.samples, args.seed, args.sampler)
    out = make_folder(Path(args.out))
    rows = run_samples(
        'tolerance', params, names, values, preset, settings['step_size'], out / 'results.jsonl',
        args.scheduler, args.workers, args.dashboard, args.resume, args.batch_size,
    )
    summary = {
        'samples': len(values),
        'seed': args.seed,
        'sampler': args.sampler,
        'scenario': "the paper's step: 5 -> 20 L/min at 0.25 s, measured over 1 s",
        **protocol,
        'distributions': [d.describe() for d in distributions],
        **summarise(rows, limits),
    }
    write_samples(out / 'samples.csv', names, values, rows, limits)
    write_text(out / 'summary.json', json_text(summary) + '\n')
    from valve_sim.analysis.studies.plots import plot_measure_cdfs, plot_measures_against

    plot_measure_cdfs(out / 'measures_cdf.png', rows, limits, f"protocol {protocol['protocol']}")
    for index, name in enumerate(names):
        plot_measures_against(
            out / f'measures_vs_{name}.png',
            name,
            SPECS[name].unit,
            values[:, index],
            rows,
            limits,
        )
    print(
        f"tolerance: protocol {protocol['protocol']}: {protocol['protocol_meaning']}; preset "
        f"{protocol['preset_pressure'] / 1e6:.4f} MPa",
        file=sys.stderr,
    )
    print_summary(summary)
    print(f'wrote {out}/samples.csv, {out}/summary.json and figures')
    return 0
