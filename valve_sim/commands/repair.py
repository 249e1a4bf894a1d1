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
Rewrite a truncated or crash-ended MCAP file into a complete one, as `mcap recover` does.

A recording cut off by kill -9, a full disk or a power cut has no summary, so
rosbags, rosbag2 and the mcap library's indexed reader refuse it. The repaired
copy holds every schema, channel, message, metadata and attachment record still
in the file (those of a chunk cut short too, when it is uncompressed), with
chunk and message indexes, statistics and summary, so any MCAP reader opens it.
The source is only read.
"""

from pathlib import Path

from valve_sim.recording.recovery import repair


def add_arguments(parser):
    parser.add_argument('bag', metavar='BAG.mcap', help='the damaged MCAP file (only read)')
    parser.add_argument(
        '-o',
        '--output',
        metavar='OUT.mcap',
        help='the complete copy (default: BAG with .repaired.mcap instead of .mcap)',
    )


def default_output(bag):
    """BAG.mcap -> BAG.repaired.mcap, beside it."""
    bag = Path(bag)
    return bag.with_name(f'{bag.stem}.repaired.mcap')


def run(args):
    report = repair(args.bag, args.output or default_output(args.bag))
    print(report.summary())
    return 0
