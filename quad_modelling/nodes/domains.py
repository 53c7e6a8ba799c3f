"""A ROS domain of its own for a test process or a ``run-bag`` run (no rclpy imported).

DDS participants in one ``ROS_DOMAIN_ID`` discover each other; two test processes (or two
``run-bag`` runs) that pick the same domain see each other's topics and mix their
samples. ``pid % 90`` collided whenever two pids were 90 apart. :func:`claim_domain`
instead takes an exclusive ``flock`` on one lock file per domain (``<tmp>/quad_modelling_ros_domain_<id>.lock``)
and keeps it for the life of the process (its node children run inside that life): a domain
is handed to one holder at a time on this machine, whatever the pids; a crashed holder's lock
goes with its process.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path

from quad_modelling.errors import ConfigError

DOMAIN_IDS = range(10, 100)
"""Domains handed out: 10-99 keep Fast DDS's ports (7400 + 250 x domain + ...) below Linux's ephemeral range
(32768-) as the ROS 2 docs advise for ids up to 101; 0-9 are left to people's own graphs."""

_held: list = []
"""Open lock files of the domains this process holds (closing one would release it)."""


def lock_path(domain: int, directory: Path | None = None) -> Path:
    return Path(directory or tempfile.gettempdir()) / f"quad_modelling_ros_domain_{domain}.lock"


def claim_domain(directory: Path | None = None) -> int:
    """A domain id in :data:`DOMAIN_IDS` no other live holder has claimed; held until this process ends.

    The search starts at an offset of the pid (holders started together rarely probe the same
    ids). ConfigError when every domain is held.
    """
    start = os.getpid() % len(DOMAIN_IDS)
    for i in range(len(DOMAIN_IDS)):
        domain = DOMAIN_IDS[(start + i) % len(DOMAIN_IDS)]
        handle = open(lock_path(domain, directory), "a")  # noqa: SIM115 -- kept open: the lock lives as long as the file
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            continue
        _held.append(handle)
        return domain
    raise ConfigError(f"every ROS domain {DOMAIN_IDS.start}-{DOMAIN_IDS.stop - 1} is held by another process on this machine "
                      "(set ROS_DOMAIN_ID yourself)")
