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
Bag I/O: MCAP as rosbag2 writes it, the tick messages as CDR bytes, a bag's signals.

Lives here: the MCAP writer and reader, rosbag2 metadata, a damaged file read record
by record (mcap_scan) and repaired (recovery), a few topics read through the indexes
(mcap_index), the CDR message layout, valve_node's topic layout and the offline bag
writers, a bag read into signals (signal_reader:
read_recording, decoders injected as the mcap library's decoder factories), the
scenario runner's tick bags.
May import: valve_sim.core, valve_sim.analysis, message packages, mcap. No rclpy:
publishing is ros/'s (ros.replay).
"""
