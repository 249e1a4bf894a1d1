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
managed_valve_node through the standard lifecycle services, from a client in another process.

One node (on the system clock, with a fault schedule file) goes through every
transition in file order: configure (nothing published), activate (ticks at the steady
state of the present inputs), deactivate (silent), activate again at a new inlet flow,
the halt path (an overpressure deactivates it, the reason on /diagnostics), cleanup,
a configure that fails on a broken schedule file (ErrorProcessing, then Unconfigured),
a configure that works again, the bring-up client of docs/valve_node.md, and shutdown.
Each transition is checked on ~/get_state, ~/get_available_transitions and
~/transition_event.
"""

import re
import subprocess
import sys
import time

from lifecycle_msgs.msg import Transition, TransitionEvent
from lifecycle_msgs.srv import ChangeState, GetAvailableTransitions, GetState
import pytest
from valve_harness import Probe, REPO, stop_node, TIMEOUT
from valve_sim.core.model import P_S
from valve_sim.core.simulation import LITRE_PER_MINUTE
from valve_sim.core.steady_state import steady_state


pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures('valve_node_kernels')]

NAMESPACE = '/managed'
VALVE_PAGE = REPO / 'docs' / 'valve_node.md'  # its Python block of node 'bring_up'
AMBIENT = 101325.0  # [Pa]
QUIET = 0.3  # [s] without a message: the node publishes nothing (it ticks at 1 kHz)
SCHEDULE = 'events:\n  - {t: 1000.0, set: {fault.seat_leakage_diameter: 0.0}}\n'


class LifecycleClient(Probe):
    """The probe, with clients of the lifecycle services and the transition events."""

    def __init__(self, context):
        self.events = []  # TransitionEvent, as they came
        super().__init__(context, NAMESPACE)
        name = self.valve_name
        self.change = self.node.create_client(ChangeState, f'{name}/change_state')
        self.state = self.node.create_client(GetState, f'{name}/get_state')
        self.transitions = self.node.create_client(
            GetAvailableTransitions, f'{name}/get_available_transitions')
        self.node.create_subscription(TransitionEvent, f'{name}/transition_event',
                                      self._on_event, 100)

    def _on_event(self, event):
        with self.condition:
            self.events.append((event.start_state.label, event.goal_state.label))

    def current(self):
        """Return the label of the node's state (~/get_state)."""
        return self._result(self.state.call_async(GetState.Request())).current_state.label

    def available(self):
        """Return the labels of the transitions available now (~/get_available_transitions)."""
        response = self._result(self.transitions.call_async(GetAvailableTransitions.Request()))
        return {t.transition.label for t in response.available_transitions}

    def transition(self, transition_id):
        """Return whether the transition asked for on ~/change_state succeeded."""
        request = ChangeState.Request(transition=Transition(id=transition_id))
        return self._result(self.change.call_async(request)).success

    def quiet(self):
        """Wait until nothing came for QUIET s (the messages on their way drained); count."""
        deadline = time.monotonic() + TIMEOUT
        while time.monotonic() < deadline:
            with self.condition:
                count = self.count()
            if not self._wait(lambda: self.count() > count, QUIET):
                return count
        raise AssertionError(f'supply_pressure still published after {TIMEOUT} s')

    def wait_for_event(self, start, goal):
        """Wait for the transition event start -> goal."""
        self.wait_for(lambda: (start, goal) in self.events, f'transition event {start}->{goal}')


@pytest.fixture(scope='module')
def managed(context, tmp_path_factory):
    """Start managed_valve_node in NAMESPACE; yields (client, schedule file, log file)."""
    folder = tmp_path_factory.mktemp('managed')
    schedule, log_path = folder / 'schedule.yaml', folder / 'managed.log'
    schedule.write_text(SCHEDULE)
    with open(log_path, 'w') as log:
        process = subprocess.Popen(
            [sys.executable, '-m', 'valve_sim.ros.managed_valve_node', '--ros-args',
             '-r', f'__ns:={NAMESPACE}', '-p', f'fault_schedule:={schedule}'],
            stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
    client = LifecycleClient(context)
    try:
        assert client.change.wait_for_service(timeout_sec=TIMEOUT), 'no ~/change_state'
        yield client, schedule, log_path, process
    finally:
        client.close()
        stop_node(process)


def test_it_starts_unconfigured_with_configure_and_shutdown_available(managed):
    client, *_ = managed
    assert client.current() == 'unconfigured'
    assert client.available() == {'configure', 'shutdown'}


def test_configure_sets_it_up_and_publishes_nothing(managed):
    client, *_ = managed
    assert client.transition(Transition.TRANSITION_CONFIGURE)
    client.wait_for_event('configuring', 'inactive')
    assert client.current() == 'inactive'
    assert client.available() == {'activate', 'cleanup', 'shutdown'}
    client.wait_for(lambda: client.inlet.get_subscription_count() > 0, 'inlet_flow subscribed')
    assert client.parameters.wait_for_services(timeout_sec=TIMEOUT)
    assert client.get_parameters('publish_rate') == {'publish_rate': 1000.0}
    # a tick would publish within a millisecond: QUIET s of silence is nothing published
    assert not client._wait(lambda: client.count() > 0, QUIET), 'published while inactive'


def test_activate_ticks_from_the_steady_state_of_the_present_flow(managed, reference):
    client, *_ = managed
    assert client.transition(Transition.TRANSITION_ACTIVATE)
    assert client.current() == 'active'
    assert client.available() == {'deactivate', 'shutdown'}
    first = client.wait_for_new_samples(1)
    expected = steady_state(reference, 5.0 * LITRE_PER_MINUTE)[P_S] + AMBIENT
    assert first[1] == pytest.approx(expected, rel=1e-6)


def test_deactivate_stops_publishing_and_activate_resolves_at_the_new_flow(managed, reference):
    client, *_ = managed
    assert client.transition(Transition.TRANSITION_DEACTIVATE)
    assert client.current() == 'inactive'
    client.wait_for_event('deactivating', 'inactive')
    last_inactive = client.quiet()
    client.send_flow(10.0 * LITRE_PER_MINUTE)  # taken while inactive
    assert not client._wait(lambda: client.count() > last_inactive, QUIET), 'published inactive'
    assert client.transition(Transition.TRANSITION_ACTIVATE)
    client.wait_for(lambda: client.count() > last_inactive, 'samples after activate')
    with client.condition:
        first = client.pressures['supply_pressure'][last_inactive]
    expected = steady_state(reference, 10.0 * LITRE_PER_MINUTE)[P_S] + AMBIENT
    assert first[1] == pytest.approx(expected, rel=1e-6)


def test_an_overpressure_deactivates_it_with_the_reason_on_diagnostics(managed, reference):
    client, *_ = managed
    p_s = client.latest()[1] - AMBIENT
    assert client.set_parameters(supply_pressure_limit=p_s + 1e4)[-1].successful
    client.send_flow(20.0 * LITRE_PER_MINUTE)  # p_s rises past the limit
    values = client.wait_for_diagnostics(
        lambda values: values['name'].endswith(': lifecycle'), 'the deactivation report')
    client.wait_for_event('deactivating', 'inactive')
    assert client.current() == 'inactive'
    assert values['level'] == 2 and 'overpressure' in values['message']
    assert values['lifecycle_state'] == 'inactive'
    held = client.quiet()  # nothing published after the halt
    assert client.set_parameters(supply_pressure_limit=0.0)[-1].successful
    assert client.transition(Transition.TRANSITION_ACTIVATE)
    client.wait_for(lambda: client.count() > held, 'samples after activate')
    expected = steady_state(reference, 20.0 * LITRE_PER_MINUTE)[P_S] + AMBIENT
    with client.condition:
        assert client.pressures['supply_pressure'][held][1] == pytest.approx(expected, rel=1e-6)


def test_cleanup_undoes_the_configuration(managed):
    client, *_ = managed
    assert client.transition(Transition.TRANSITION_DEACTIVATE)
    assert client.transition(Transition.TRANSITION_CLEANUP)
    client.wait_for_event('cleaningup', 'unconfigured')
    assert client.current() == 'unconfigured'
    client.wait_for(lambda: client.inlet.get_subscription_count() == 0, 'inlet_flow gone')


def test_a_failing_configure_goes_through_errorprocessing_to_unconfigured(managed):
    client, schedule, log_path, _ = managed
    schedule.write_text('events: [{t: -1.0, set: {fault.no_such_fault: 1.0}}]\n')
    assert not client.transition(Transition.TRANSITION_CONFIGURE)
    client.wait_for_event('configuring', 'errorprocessing')
    client.wait_for_event('errorprocessing', 'unconfigured')
    assert client.current() == 'unconfigured'
    client.wait_for(lambda: 'configure failed' in log_path.read_text(), 'the logged reason')
    schedule.write_text(SCHEDULE)  # repaired: it configures again
    assert client.transition(Transition.TRANSITION_CONFIGURE)
    assert client.current() == 'inactive'


def test_the_documented_bring_up_client_activates_it(managed, tmp_path):
    client, *_ = managed
    (block,) = [block for block in re.findall(r'```python\n(.*?)```', VALVE_PAGE.read_text(),
                                              flags=re.DOTALL) if "'bring_up'" in block]
    script = tmp_path / 'bring_up.py'
    script.write_text(block)
    done = subprocess.run([sys.executable, str(script), '--ros-args', '-r', f'__ns:={NAMESPACE}'],
                          capture_output=True, text=True, timeout=TIMEOUT)
    assert done.returncode == 0, done.stderr
    assert done.stdout == 'relief_valve is active\n'
    assert client.current() == 'active'
    client.wait_for_new_samples(1)


def test_shutdown_finalizes_it_and_the_process_goes_on_until_sigint(managed):
    client, _, log_path, process = managed
    assert client.transition(Transition.TRANSITION_ACTIVE_SHUTDOWN)
    client.wait_for_event('shuttingdown', 'finalized')
    assert client.current() == 'finalized'
    assert process.poll() is None, log_path.read_text()
