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

"""Test isolation (../shared/spec/platform.md): every test session picks its own
ROS_DOMAIN_ID and keeps discovery on localhost, before anything imports rclpy,
so parallel or leftover runs never cross-talk. Child processes inherit both."""

import os
import random


os.environ['ROS_DOMAIN_ID'] = str(random.SystemRandom().randint(1, 101))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('MPLBACKEND', 'Agg')


import pytest  # noqa: E402  (after the environment is set)


@pytest.fixture(scope='module')
def context():
    """An rclpy context of its own for a test module (nodes in the test process)."""
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context)
    yield context
    context.try_shutdown()


@pytest.fixture(scope='session')
def reference():
    """The validated parameters of config/reference.yaml."""
    from valve_sim.core.parameters import load_parameters

    return load_parameters()[0]
