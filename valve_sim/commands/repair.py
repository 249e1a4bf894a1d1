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
The source is only read. A rosbag2 bag folder is repaired file by file into a
new folder, with its metadata.yaml (as `ros2 bag reindex` writes it).
"""

from pathlib import Path

from valve_sim.core.errors import InputFileError
from valve_sim.recording.recovery import repair, repair_folder


def add_arguments(parser):
    parser.add_argument('bag', metavar='BAG',
                        help='the damaged MCAP file, or a rosbag2 bag folder (only read)')
    parser.add_argument('-o', '--output', metavar='OUT',
                        help='the complete copy (default: BAG.repaired.mcap beside a file, '
                        'BAG_repaired/ beside a folder; written whole, through a temporary '
                        'file; a symbolic link at a default name is replaced, not followed)')


def default_output(bag):
    """Return BAG.repaired.mcap for a file, BAG_repaired for a folder."""
    bag = Path(bag)
    if bag.is_dir():
        return bag.with_name(f'{bag.name}_repaired')
    return bag.with_name(f'{bag.stem}.repaired.mcap')


def run(args):
    output = Path(args.output) if args.output else default_output(args.bag)
    if not Path(args.bag).is_dir():
        print(repair(args.bag, output, explicit=bool(args.output)).summary())
        return 0
    if not args.output and output.is_symlink():
        raise InputFileError(
            f'{output} is a symbolic link, which valve-sim does not write through unless '
            'named: give -o OUT'
        )
    for report in repair_folder(args.bag, output):
        print(report.summary())
    print(f'wrote {output}, a bag folder with its metadata.yaml')
    return 0
