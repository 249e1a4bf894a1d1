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
A DDS domain of its own for a run of nodes on this machine, discovery kept on localhost.

Test sessions, the demo and the benchmarks each start nodes that must not hear
another run's nodes. A random ROS_DOMAIN_ID alone collides now and then when
several runs share a machine, so the domain is also claimed with an exclusive
lock file (released when the process ends, even on kill -9).
"""
import fcntl
import os
from pathlib import Path
import random
import tempfile

from valve_sim.core.errors import UnavailableError

DOMAIN_IDS = range(1, 102)   # 0-101 are the IDs Fast DDS maps to ports; 0 is the default
LOCK_FOLDER = Path(tempfile.gettempdir()) / 'valve_sim_domains'
_held_locks = {}  # domain: the open lock file this process holds it by


def claim_domain(keep_existing=True):
    """
    Set ROS_DOMAIN_ID to a domain no other run on this machine holds, and hold it; return it.

    With keep_existing, a ROS_DOMAIN_ID already in the environment (the user's, or a
    parent run's) is kept if no other process holds it (hold_domain): a run that brings
    its own nodes never shares a domain with another run's. ROS_AUTOMATIC_DISCOVERY_RANGE
    is set to LOCALHOST unless set. Child processes inherit both.
    """
    if keep_existing:
        return hold_domain()
    domain = claim_apart()
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    return domain


def claim_apart():
    """
    Hold a domain no run on this machine holds, this process's included; return it.

    ROS_DOMAIN_ID is left as it is: for nodes that must stay apart from the rest of
    this process's runs (the test kit's session valve, up while other tests run their
    own nodes in the environment's domain).
    """
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    candidates = [domain for domain in DOMAIN_IDS if domain not in _held_locks]
    random.SystemRandom().shuffle(candidates)
    for domain in candidates:
        if _lock(domain):
            return domain
    raise UnavailableError(
        f'every ROS domain 1-101 is held by another run (locks in {LOCK_FOLDER})'
    )


def _lock(domain):
    """Hold domain's lock for this process; return whether it is this process's now."""
    if domain in _held_locks:
        return True
    LOCK_FOLDER.mkdir(exist_ok=True)
    handle = open(LOCK_FOLDER / f'{domain}.lock', 'w')
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        handle.close()
        return False
    _held_locks[domain] = handle  # held until this process ends
    return True


def held_lock_fds():
    """
    Return the descriptors of the domain locks this process holds, for its node processes.

    A child that inherits them holds the domain too (flock: until every copy is closed),
    so a node left running after its run's process died keeps other runs out of its
    domain instead of answering their /clock.
    """
    return tuple(handle.fileno() for handle in _held_locks.values())


def hold_domain():
    """
    Run in a domain no other process on this machine holds: the environment's, or a new one.

    The environment's ROS_DOMAIN_ID is kept, and held, unless another process holds
    it (a second pytest-xdist worker or test run that inherited the same environment):
    then a free one is claimed (claim_domain). Returns the domain.
    """
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    current = os.environ.get('ROS_DOMAIN_ID', '')
    if current.isdigit() and _lock(int(current)):
        return int(current)
    return claim_domain(keep_existing=False)
