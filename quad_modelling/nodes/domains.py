"""The DDS environment of a graph: a ROS domain of its own for a test process or a ``run-bag`` run, the
discovery settings (:func:`discovery_environment`) and the Fast DDS profile (:func:`use_dds_profile`); all three
for ``run-bag``'s nodes: :func:`ros_environment`.
No rclpy imported.

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
from quad_modelling.io.dds_profile import DDS_PROFILE_ENV, profile_with_defaults

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


DISCOVERY_MODES = ("localhost", "subnet", "env")
"""``run-bag --discovery``: how far the nodes look for each other (:func:`discovery_environment`)."""

DISCOVERY_VARIABLES = ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY")
"""The environment variables of ROS 2 (Jazzy) discovery that :func:`discovery_environment` sets or keeps."""


def discovery_environment(env: dict, mode: str) -> dict:
    """``env`` with the discovery variables of ``mode`` (:data:`DISCOVERY_MODES`), in place; returns ``env``.

    * ``localhost``: ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and no ``ROS_STATIC_PEERS`` (static
      peers are contacted whatever the range): nothing leaves this host.
    * ``subnet``: ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`` (multicast discovery on the attached
      networks, the Fast DDS default); ``ROS_STATIC_PEERS`` kept as the user set them (``;``-separated
      addresses or host names, contacted by unicast: for networks without multicast).
    * ``env``: ``ROS_AUTOMATIC_DISCOVERY_RANGE`` and ``ROS_STATIC_PEERS`` exactly as the user set them.

    The deprecated ``ROS_LOCALHOST_ONLY`` is removed except in ``env`` (it would override the range).
    """
    if mode not in DISCOVERY_MODES:
        raise ConfigError(f"--discovery {mode!r}: must be one of {', '.join(DISCOVERY_MODES)}")
    if mode == "env":
        return env
    env.pop("ROS_LOCALHOST_ONLY", None)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST" if mode == "localhost" else "SUBNET"
    if mode == "localhost":
        env.pop("ROS_STATIC_PEERS", None)
    return env


def use_dds_profile(environ: dict | None = None) -> str:
    """Point Fast DDS at ``config/fastdds.xml`` (50 ms writer heartbeat), or, when ``environ`` (default
    ``os.environ``) already names a profile file in ``FASTRTPS_DEFAULT_PROFILES_FILE``, at that file with our
    writer settings merged in where it does not set them (:mod:`quad_modelling.io.dds_profile`: the user's
    settings win). Updates ``environ``; returns the file in use. Call before ``rclpy.init``.
    ConfigError for a profile file that cannot be read or parsed.
    """
    from quad_modelling.core.vehicle import config_dir

    environ = os.environ if environ is None else environ
    ours = config_dir() / "fastdds.xml"
    given = environ.get(DDS_PROFILE_ENV, "").strip()
    environ[DDS_PROFILE_ENV] = str(ours if not given or Path(given) == ours else profile_with_defaults(given, ours))
    return environ[DDS_PROFILE_ENV]


def ros_environment(discovery: str = "localhost", remote: tuple[str, ...] = ()) -> dict:
    """The environment of ``run-bag``'s nodes: discovery per ``discovery`` (:func:`discovery_environment`); the Fast
    DDS profile (ours, or the user's with our writer heartbeat merged in: :func:`use_dds_profile`); a domain no other
    run holds unless set (:func:`claim_domain`, held until this process ends). With nodes on another host (``remote``,
    the ``--nodes`` groups started elsewhere) ROS_DOMAIN_ID must be set: ConfigError otherwise."""
    env = discovery_environment(dict(os.environ), discovery)
    if not env.get("ROS_DOMAIN_ID"):
        if remote:
            raise ConfigError(f"--nodes: {', '.join(remote)} run on another host; set ROS_DOMAIN_ID (the same number "
                              "on every host) so the two halves of the graph meet")
        env["ROS_DOMAIN_ID"] = str(claim_domain())
    use_dds_profile(env)
    env.setdefault("PYTHONUNBUFFERED", "1")
    env.setdefault("MPLBACKEND", "Agg")
    return env
