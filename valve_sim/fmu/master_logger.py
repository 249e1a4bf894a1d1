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
The master's FMI logger, called directly: errors reach it whatever its logging setting.

pythonfmu 0.7's binary hands the slave's messages to the master only while the master
has debug logging on, and logs its own (a failed fmi2Instantiate, a fatal) with a NULL
category. It passes the slave the address of its C++ logger object (the 'logger'
argument); on Linux x86_64 (libstdc++) that object holds, at fixed offsets, the
debug-logging flag, the instance name and the master's fmi2CallbackFunctions.
MasterLogger.attach() reads them, checked against the instance name, or returns None (another
platform or build: the slave queues its messages through pythonfmu as before). Attached,
the slave's messages go to the master's logger directly, each with its category, errors
and warnings always, the rest while debug logging is on; pythonfmu's own flag is cleared,
so it passes no NULL category. Standard library only: the FMU carries a copy in its
resources/ to report a valve_sim it cannot import (unavailable_slave).
"""

import ctypes
import platform
import sys


# The fields of pythonfmu 0.7's Fmi2Logger (Itanium C++ ABI, libstdc++), byte offsets:
# vtable pointer, bool debugLogging_, std::string instanceName_ (pointer, length, 16-byte
# buffer), std::vector<std::string> categories_ (3 pointers), fmi2CallbackFunctions* f_.
FLAG, NAME, NAME_LENGTH, NAME_BUFFER, CATEGORIES, CALLBACKS = 8, 16, 24, 32, 48, 72
STATUS_NAMES = ('Ok', 'Warning', 'Discard', 'Error', 'Fatal')  # fmi2Status 0 to 4
LOGGER = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p,
                          ctypes.c_char_p)


class Callbacks(ctypes.Structure):
    """fmi2CallbackFunctions: the master's logger first, its environment last."""

    _fields_ = [('logger', ctypes.c_void_p), ('allocate_memory', ctypes.c_void_p),
                ('free_memory', ctypes.c_void_p), ('step_finished', ctypes.c_void_p),
                ('environment', ctypes.c_void_p)]


def word(address):
    """Return the 8-byte word at address (inside the logger object)."""
    return ctypes.c_uint64.from_address(address).value


class MasterLogger:
    """The master's logger of one instance, found through pythonfmu's logger object."""

    def __init__(self, address, name, callbacks):
        self._flag = ctypes.c_uint8.from_address(address + FLAG)
        self._name = name
        self._callbacks = callbacks
        self._logger = LOGGER(callbacks.logger)
        self.debug = bool(self._flag.value)
        self._flag.value = 0  # pythonfmu logs nothing itself from now on (NULL categories)

    @classmethod
    def attach(cls, address, instance_name):
        """Return the MasterLogger behind pythonfmu's logger address, or None if unsure."""
        if (sys.platform != 'linux' or platform.machine() != 'x86_64'
                or not isinstance(address, int) or address <= 0 or address % 8):
            return None
        name = instance_name.encode()
        length, pointer = word(address + NAME_LENGTH), word(address + NAME)
        begin, end, capacity = (word(address + CATEGORIES + 8 * i) for i in range(3))
        if (ctypes.c_uint8.from_address(address + FLAG).value > 1 or length != len(name)
                or not begin <= end <= capacity or (begin == 0) != (capacity == 0)):
            return None
        if len(name) < 16 and pointer != address + NAME_BUFFER:  # libstdc++ keeps it inline
            return None
        if pointer == 0 or ctypes.string_at(pointer, length) != name:
            return None
        callbacks = word(address + CALLBACKS)
        if callbacks == 0 or callbacks % 8:
            return None
        callbacks = Callbacks.from_address(callbacks)
        return cls(address, name, callbacks) if callbacks.logger else None

    def wants(self, status):
        """Return whether a message of status (0 ok .. 4 fatal) goes to the master."""
        if self._flag.value:  # fmi2SetDebugLogging turned it on again
            self.debug, self._flag.value = True, 0
        return status > 0 or self.debug

    def log(self, message, status, category=None):
        """Call the master's logger; '%' doubled, as it takes the message as a format."""
        category = category or (f'logStatus{STATUS_NAMES[int(status)]}' if 0 < status < 5
                                else 'logAll')  # pythonfmu's categories
        self._logger(self._callbacks.environment, self._name, int(status), category.encode(),
                     str(message).replace('%', '%%').encode())

    def silence(self):
        """Keep pythonfmu from logging what follows (its NULL-category fatal)."""
        self._flag.value = 0


def unavailable_slave(error, base):
    """
    Return a slave class that reports why the FMU cannot run and fails fmi2Instantiate.

    error: the exception of importing valve_sim's slave; base: pythonfmu's Fmi2Slave.
    """
    reason = (
        f'the valve_sim FMU cannot start: {type(error).__name__}: {error}. The Python '
        f'{sys.version.split()[0]} this FMU runs in ({sys.prefix}) needs valve_sim and its '
        "dependencies: `pip install -e '.[wheels,fmu]'` in a valve_sim clone, or set "
        'PYTHONPATH (and, in a C master, LD_PRELOAD and PYTHONHOME) as docs/fmu.md says: '
        '`python -m valve_sim.fmu.environment` prints them'
    )

    class ReliefValve(base):
        """Stands in for the slave where valve_sim cannot be imported: says why, fails."""

        def __init__(self, **kwargs):
            master = MasterLogger.attach(kwargs.get('logger'), kwargs.get('instance_name', ''))
            if master is None:
                print(reason, file=sys.stderr)
            else:
                master.log(reason, 3)
                master.silence()
            raise RuntimeError(reason)

        def do_step(self, current_time, step_size):
            return False

    return ReliefValve
