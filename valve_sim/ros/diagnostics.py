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
The /diagnostics conventions of valve_sim's nodes, as diagnostic_updater has them.

Status name: '<node name>: <task>', the node's actual name (after any remapping, as
`--ros-args -r __node:=other`; without namespace or leading slash), as
diagnostic_updater's Updater.publish builds it. hardware_id: the node's read-only
parameter hardware_id, by default its fully qualified name (/ns/name): the same
every run, different for two nodes; a bench sets it to the device the node stands
for. Levels: DiagnosticStatus OK (0), WARN (1) and ERROR (2); what puts each node
in which is documented with the node (docs/valve_node.md, docs/analyser.md).
Period: valve_node's read-only parameter diagnostic_updater.period, the name and
default (1 s) of diagnostic_updater's own.
"""

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, ParameterType


HARDWARE_ID = 'hardware_id'
PERIOD = 'diagnostic_updater.period'
PERIOD_RANGE = (0.05, 60.0)  # [s] faster than 20 Hz would cost ticks their time


def status_name(node, task):
    """Name of a node's status for a task, e.g. 'relief_valve: valve model'."""
    return f'{node.get_name()}: {task}'


def declare_hardware_id(node):
    """Declare the read-only string parameter hardware_id; return its value."""
    descriptor = ParameterDescriptor(
        name=HARDWARE_ID,
        description=(
            'hardware_id of the /diagnostics statuses (default: the fully qualified node '
            'name; set it to the device this node stands for)'
        ),
        read_only=True,
    )
    return node.declare_parameter(
        HARDWARE_ID, node.get_fully_qualified_name(), descriptor
    ).value


def declare_period(node):
    """Declare the read-only double parameter diagnostic_updater.period [s]; return its value."""
    low, high = PERIOD_RANGE
    descriptor = ParameterDescriptor(
        name=PERIOD,
        type=ParameterType.PARAMETER_DOUBLE,
        description=(
            'period of the /diagnostics report and of the housekeeping that counts the '
            "inputs, on the steady clock [s] (diagnostic_updater's parameter and default)"
        ),
        read_only=True,
        floating_point_range=[FloatingPointRange(from_value=low, to_value=high)],
    )
    return node.declare_parameter(PERIOD, 1.0, descriptor).value
