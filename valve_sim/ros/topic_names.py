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
A topic name a user gives (scenario run --wait-topic), checked by rcl's rules before use.

topic_problem() expands it as a node at the root would (~ and {node} included) and
validates the full name, so a bad name is one line before any node starts, never an
RCLError traceback from a node that is already running.
"""

import re

from rclpy.exceptions import NameValidationException
from rclpy.expand_topic_name import expand_topic_name
from rclpy.validate_full_topic_name import validate_full_topic_name


def topic_problem(text, node_name='scenario_driver'):
    """Return why text is no valid ROS topic name (rcl's words), or None if it is one."""
    try:
        validate_full_topic_name(expand_topic_name(text, node_name, '/'))
    except (ValueError, NameValidationException) as error:  # rcl's, then rclpy's
        return re.sub(r'^.*(?:is invalid|Invalid topic name): |, at \S+$', '',
                      str(error).splitlines()[0]).rstrip(':')
    return None
