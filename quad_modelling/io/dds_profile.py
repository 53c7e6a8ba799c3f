"""Fast DDS XML profiles: the project's writer settings merged into a user's profile file.

Fast DDS 2.x (ROS 2 Jazzy's ``rmw_fastrtps_cpp``) reads one XML file, named by the environment
variable ``FASTRTPS_DEFAULT_PROFILES_FILE``, when a process creates its first participant. The
nodes need a short writer heartbeat (``config/fastdds.xml``: 50 ms instead of 3 s, see that
file); a user may need their own file (transports, interface whitelists, discovery servers).
Setting the variable to ours would drop theirs; keeping theirs would drop ours. So:

* **Precedence: the user's settings win.** Their file is kept element for element; from ours
  only what their *default* ``data_writer`` profile (``is_default_profile="true"``) does not set
  is added to it (element by element: a ``<times>`` of theirs without ``<heartbeatPeriod>`` gets
  ours, one with it keeps theirs). With no default ``data_writer`` profile of theirs, ours is
  added as one. Participant, data_reader, topic and transport profiles, ``<log>``, ``<types>``
  are never touched.
* A file that already sets everything ours sets is used as is (no copy).
* Otherwise the merge is written to ``<tmp>/quad_modelling_fastdds_<hash>.xml`` (the system
  temporary directory; the name is a hash of the merged text, so every process merging the same
  file shares one copy, written atomically), and the variable points there. Its first comment
  names the user's file and what was added.

Profiles are matched by tag name with or without the eProsima namespace, in a ``<dds><profiles>``
or a bare ``<profiles>`` root. No rclpy here: the nodes call :func:`profile_with_defaults` before
``rclpy.init`` (:func:`quad_modelling.nodes.common.use_dds_profile`).
"""

from __future__ import annotations

import copy
import hashlib
import os
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

from quad_modelling.errors import ConfigError

DDS_PROFILE_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"
"""Environment variable Fast DDS 2.x reads its XML profiles from (at participant creation)."""

FASTDDS_NAMESPACE = "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"
"""XML namespace of Fast DDS profile files (optional in the files Fast DDS accepts)."""

MERGED_PREFIX = "quad_modelling_fastdds_"
"""File name prefix of merged profiles in the temporary directory."""


def _local(tag) -> str:
    return tag.rpartition("}")[2] if isinstance(tag, str) else ""


def _namespace(tag: str) -> str:
    return tag[1:].partition("}")[0] if tag.startswith("{") else ""


def _parse(text: str, source: str) -> ET.Element:
    try:
        return ET.fromstring(text, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    except ET.ParseError as err:
        raise ConfigError(f"{source}: not a readable Fast DDS XML profile file: {err}") from err


def _profiles(root: ET.Element, source: str) -> ET.Element:
    """The ``<profiles>`` element of a ``<dds>`` or ``<profiles>`` root; ConfigError when there is none."""
    if _local(root.tag) == "profiles":
        return root
    if _local(root.tag) == "dds":
        found = next((child for child in root if _local(child.tag) == "profiles"), None)
        if found is not None:
            return found
        ns = _namespace(root.tag)
        return ET.SubElement(root, f"{{{ns}}}profiles" if ns else "profiles")
    raise ConfigError(f"{source}: root element <{_local(root.tag)}> is not a Fast DDS profile file (<dds> or <profiles>)")


def _default_writer(profiles: ET.Element) -> ET.Element | None:
    return next((p for p in profiles if _local(p.tag) == "data_writer" and p.get("is_default_profile", "").lower() == "true"),
                None)


def _in_namespace(element: ET.Element, ns: str) -> ET.Element:
    """A deep copy of ``element`` with every tag moved into namespace ``ns`` ('' = none)."""
    element = copy.deepcopy(element)
    for item in element.iter():
        if isinstance(item.tag, str):
            item.tag = f"{{{ns}}}{_local(item.tag)}" if ns else _local(item.tag)
    return element


def _fill_missing(theirs: ET.Element, ours: ET.Element, ns: str, path: str, added: list[str]) -> None:
    """Add to ``theirs`` every child element of ``ours`` whose tag it lacks; recurse into the ones both have."""
    for child in ours:
        if not isinstance(child.tag, str):
            continue  # a comment
        name = _local(child.tag)
        match = next((c for c in theirs if _local(c.tag) == name), None)
        if match is None:
            theirs.append(_in_namespace(child, ns))
            added.append(f"{path}/{name}")
        elif len(child):
            _fill_missing(match, child, ns, f"{path}/{name}", added)


def merge_profiles(user_text: str, ours_text: str, user_source: str = "user profile") -> tuple[str | None, list[str]]:
    """The user's profile file text with the settings of ours' default ``data_writer`` profile it lacks (module doc).

    Returns (merged XML text, the settings added as ``data_writer/times/heartbeatPeriod`` paths), or
    (None, []) when the user's file already sets every one. ConfigError for a file that is not a
    Fast DDS profile (``user_source`` names it in the message).
    """
    user_root = _parse(user_text, user_source)
    user_profiles = _profiles(user_root, user_source)
    ours_writer = _default_writer(_profiles(_parse(ours_text, "config/fastdds.xml"), "config/fastdds.xml"))
    if ours_writer is None:
        raise ConfigError("config/fastdds.xml: no default data_writer profile (is_default_profile=\"true\")")
    ns = _namespace(user_profiles.tag)
    theirs = _default_writer(user_profiles)
    added: list[str] = []
    if theirs is None:
        user_profiles.append(_in_namespace(ours_writer, ns))
        added.append(f"data_writer profile {ours_writer.get('profile_name')!r} (default)")
    else:
        _fill_missing(theirs, ours_writer, ns, "data_writer", added)
    if not added:
        return None, []
    user_root.insert(0, ET.Comment(f" merged by quad_modelling from {user_source}: added {', '.join(added)}; "
                                   "everything else is that file's "))
    if ns:
        ET.register_namespace("", ns)
    return ET.tostring(user_root, encoding="unicode", xml_declaration=True) + "\n", added


def profile_with_defaults(user_file: str | os.PathLike, ours_file: str | os.PathLike, directory: Path | None = None) -> Path:
    """The profile file to give Fast DDS: ``user_file`` itself when it sets everything ``ours_file`` sets, else
    their merge (:func:`merge_profiles`) written atomically to ``directory`` (default: the system temporary
    directory) as ``quad_modelling_fastdds_<hash>.xml``. ConfigError when ``user_file`` cannot be read or parsed."""
    user_file = Path(user_file)
    try:
        user_text = user_file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{DDS_PROFILE_ENV}={str(user_file)!r}: cannot read the Fast DDS profile: {err}") from err
    merged, _ = merge_profiles(user_text, Path(ours_file).read_text(encoding="utf-8"), f"{DDS_PROFILE_ENV}={user_file}")
    if merged is None:
        return user_file
    directory = Path(directory or tempfile.gettempdir())
    target = directory / f"{MERGED_PREFIX}{hashlib.sha256(merged.encode()).hexdigest()[:16]}.xml"
    try:
        if target.is_file() and target.read_text(encoding="utf-8") == merged:
            return target
        staging = directory / f".{target.name}.{os.getpid()}.tmp"
        staging.write_text(merged, encoding="utf-8")
        os.replace(staging, target)
    except OSError as err:
        raise ConfigError(f"{DDS_PROFILE_ENV}: cannot write the merged Fast DDS profile {target}: {err}") from err
    return target
