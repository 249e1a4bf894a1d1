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
Which settings and parameter changes are events that end a step's window.

An event (docs/measures.md, "Where a window ends") is a change of a valve_node setting
that changes the valve's response or what its sensors show (changes_the_model): a model
parameter, the preset, the step size, the ambient or tank pressure, a fault or sensor
setting, the fault schedule. publish_rate, input_timeout, initial_inlet_flow and every
name outside the parameter catalogue (use_sim_time, hardware_id, ...) are none. A setting
set to the value it already had is no change either. Three sources, one rule:

- SettingChanges.update: snapshots of every setting (valve_node's fault_status);
- SettingChanges.change: partial changes against the values known (a scenario's events,
  from its start values);
- ParameterChanges: rcl_interfaces/msg/ParameterEvent messages (/parameter_events) of
  the nodes in valve_node's namespace, each node's values known from its declarations
  (new_parameters) and earlier changes. A changed parameter whose earlier value was
  never seen (the recording began after valve_node declared it) counts as a change:
  the measures of a window it may have cut are null rather than made up.

Messages are read by their fields (rclpy's or mcap_ros2's decoded objects alike).
"""

from valve_sim.core.catalogue import section_of


# valve_node's settings that change neither the valve's response nor its sensors' signals.
NOT_MODEL_SETTINGS = frozenset({'publish_rate', 'input_timeout', 'initial_inlet_flow'})
# rcl_interfaces/msg/ParameterType: the ParameterValue field holding each type's value
PARAMETER_FIELDS = {
    1: 'bool_value', 2: 'integer_value', 3: 'double_value', 4: 'string_value',
    5: 'byte_array_value', 6: 'bool_array_value', 7: 'integer_array_value',
    8: 'double_array_value', 9: 'string_array_value',
}


def changes_the_model(name):
    """Whether a change of valve_node's parameter name is an event (module docstring)."""
    section = section_of(name)
    return section not in (None, 'analyser') and name not in NOT_MODEL_SETTINGS


def event_name(changes, kind='the event'):
    """Return how a reason names an event that changes {parameter name: value}."""
    return f'{kind} ' + ', '.join(f'{name} = {value}' for name, value in changes.items())


class SettingChanges:
    """
    The settings in effect {name: value} (known: at the start, None: from the first snapshot).

    Only names that change the model count (changes_the_model).
    """

    def __init__(self, known=None):
        self.settings = None if known is None else dict(known)

    def changed(self, changes):
        """Apply changes {name: value}; return those that change a value known or not known."""
        known = self.settings if self.settings is not None else {}
        changed = {name: value for name, value in changes.items()
                   if changes_the_model(name) and (name not in known or known[name] != value)}
        self.settings = {**known, **changes}
        return changed

    def change(self, time, changes, kind='the event'):
        """Apply changes at time [s]; return (time, what) if they change a value, else None."""
        changed = self.changed(changes)
        return (time, event_name(changed, kind)) if changed else None

    def update(self, time, settings):
        """
        Take a snapshot {name: value} of every setting at time [s].

        Returns (time, what) if it differs from the last, else None (the first is the start).
        """
        if self.settings is None:
            self.settings = dict(settings)
            return None
        return self.change(time, settings)


def parameter_value(value):
    """Return the Python value of an rcl_interfaces/msg/ParameterValue (None: not set)."""
    field = PARAMETER_FIELDS.get(getattr(value, 'type', 0))
    found = getattr(value, field, None) if field else None
    return found if isinstance(found, (bool, int, float, str)) or found is None \
        else tuple(found)


class ParameterChanges:
    """
    The events in ParameterEvent messages of the nodes in valve_node's namespace.

    namespace: '' (the root) or '/rig1', where valve_node's topics are.
    """

    def __init__(self, namespace=''):
        self.namespace = namespace.rstrip('/')
        self.nodes = {}  # fully qualified node name: its SettingChanges

    def update(self, message):
        """Take one ParameterEvent; return (time [s], what) if it changes the model, else None."""
        node = str(message.node)
        if node.rsplit('/', 1)[0] != self.namespace:
            return None
        known = self.nodes.setdefault(node, SettingChanges({}))
        known.settings.update({parameter.name: parameter_value(parameter.value)
                               for parameter in message.new_parameters})  # declared: no event
        stamp = message.stamp
        return known.change(
            stamp.sec + stamp.nanosec * 1e-9,
            {parameter.name: parameter_value(parameter.value)
             for parameter in message.changed_parameters},
            f'the parameter change on {node}:')
