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
Launch valve_node and analyser_node together (launch_ros).

    ros2 launch valve_sim valve_sim.launch.py
    ros2 launch valve_sim valve_sim.launch.py namespace:=rig1 use_sim_time:=true \
        params_file:=/path/to/my_valve.yaml output_dir:=/data/recordings

params_file is handed to valve_node as its --params-file (default: the packaged
config/reference.yaml; the node's defaults are the reference valve in any case). rcl
applies a section that names the node as it runs: `/**/relief_valve:` (what
`valve-sim calibrate` writes) in any namespace, `/rig1/relief_valve:` in /rig1,
`relief_valve:` only without a namespace; valve_node logs which sections it applied
and warns of one meant for it that does not apply. output_dir is where
analyser_node writes its MCAP recordings and measures.

    ros2 launch valve_sim valve_sim.launch.py managed:=true [autostart:=true]

runs the valve as the managed node managed_valve_node instead (docs/valve_node.md,
"Managed"), unconfigured until a lifecycle manager (or autostart:=true) configures and
activates it.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition, UnlessCondition
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import LifecycleNode, Node


PACKAGE = 'valve_sim'


def generate_launch_description():
    """Declare the six arguments and the nodes: the valve (plain or managed) and the analyser."""
    reference = os.path.join(get_package_share_directory(PACKAGE), 'config', 'reference.yaml')
    namespace = LaunchConfiguration('namespace')
    use_sim_time = LaunchConfiguration('use_sim_time')
    managed = LaunchConfiguration('managed')
    valve_parameters = [LaunchConfiguration('params_file'), {'use_sim_time': use_sim_time}]
    return LaunchDescription([
        DeclareLaunchArgument(
            'params_file',
            default_value=reference,
            description='ROS 2 parameter file for valve_node (default: the reference valve)',
        ),
        DeclareLaunchArgument(
            'namespace', default_value='', description='namespace of both nodes and their topics'
        ),
        DeclareLaunchArgument(
            'use_sim_time',
            default_value='false',
            description='follow /clock instead of the system clock (both nodes)',
        ),
        DeclareLaunchArgument(
            'output_dir',
            default_value='.',
            description="folder of analyser_node's recordings (created if missing)",
        ),
        DeclareLaunchArgument(
            'managed',
            default_value='false',
            description='run the valve as a managed (lifecycle) node, managed_valve_node',
        ),
        DeclareLaunchArgument(
            'autostart',
            default_value='false',
            description='managed: configure and activate it at launch',
        ),
        Node(
            package=PACKAGE,
            executable='valve_node',
            name='relief_valve',
            namespace=namespace,
            parameters=valve_parameters,
            output='screen',
            condition=UnlessCondition(managed),
        ),
        *(
            LifecycleNode(
                package=PACKAGE,
                executable='managed_valve_node',
                name='relief_valve',
                namespace=namespace,
                parameters=valve_parameters,
                output='screen',
                autostart=autostart,
                condition=IfCondition(PythonExpression([
                    "'", managed, "' == 'true' and '", LaunchConfiguration('autostart'),
                    f"' == '{str(autostart).lower()}'",
                ])),
            )
            for autostart in (False, True)
        ),
        Node(
            package=PACKAGE,
            executable='analyser_node',
            name='valve_analyser',
            namespace=namespace,
            parameters=[
                {'output_dir': LaunchConfiguration('output_dir'), 'use_sim_time': use_sim_time}
            ],
            output='screen',
        ),
    ])
