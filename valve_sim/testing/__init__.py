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
A test kit for users' own suites: a valve_node in lockstep, driven from a test.

    from valve_sim.testing import lockstep_valve

    with lockstep_valve(parameters={'supply_pressure_limit': '21 MPa'}) as valve:
        valve.advance(0.25)
        valve.set_flow('20 L/min')
        valve.advance(1.0)
        assert valve.measures(at=0.25)['T_s_ms'] < 600

Lives here: LockstepValve and lockstep_valve() (lockstep_valve.py), and the pytest
fixture `lockstep_valve` (pytest_plugin.py; `pytest_plugins = ['valve_sim.testing.
pytest_plugin']` in a conftest.py brings it in). The top wing: nothing imports it.
May import: every other wing, rclpy, pytest (pytest_plugin only).
"""

from valve_sim.testing.lockstep_valve import lockstep_valve, LockstepValve

__all__ = ['lockstep_valve', 'LockstepValve']
