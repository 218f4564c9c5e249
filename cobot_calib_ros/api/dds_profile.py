"""Fast DDS set up for camera images of 1 MB and more in every process the product starts.

config/fastdds_large_images.xml gives each participant a 16 MB shared-memory segment (the
default 512 KB lost most 1280x800 frames, see the file) and sends Fast DDS's own warnings and
errors to stderr (not stdout, where they broke JSON output). ``large_data_env`` returns an
environment that uses it:

- FASTRTPS_DEFAULT_PROFILES_FILE unset: that file;
- set to a profile of the user's (or the tests' test/fastdds_no_lease_check.xml) whose default
  participant configures no transports: a copy of it with the same transports added to that
  participant, and our log section if it has none (everything else of it kept), written once
  under the temporary directory;
- a profile that sets transports of its own, or that cannot be read: left as it is (its owner
  chose; a broken file is Fast DDS's to report).
"""
from __future__ import annotations

from collections.abc import Mapping
import hashlib
import os
from pathlib import Path
import tempfile
import xml.etree.ElementTree as ET

from cobot_calib_ros import paths

PROFILE_ENV = 'FASTRTPS_DEFAULT_PROFILES_FILE'
NS = 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'
TRANSPORT_TAGS = ('userTransports', 'useBuiltinTransports')


def large_data_profile() -> Path:
    return paths.config_dir() / 'fastdds_large_images.xml'


def large_data_env(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """``env`` (default os.environ) with FASTRTPS_DEFAULT_PROFILES_FILE giving the participants
    the large-image transports (module doc)."""
    out = dict(os.environ if env is None else env)
    given = out.get(PROFILE_ENV, '')
    if not given:
        out[PROFILE_ENV] = str(large_data_profile())
    elif Path(given).resolve() != large_data_profile().resolve():
        merged = _with_transports(Path(given))
        if merged is not None:
            out[PROFILE_ENV] = str(merged)
    return out


def _q(tag: str) -> str:
    return f'{{{NS}}}{tag}'


def _profiles(root: ET.Element) -> ET.Element | None:
    """The <profiles> element of a profile file's root (<profiles> itself, or under <dds>)."""
    if root.tag == _q('profiles'):
        return root
    return root.find(_q('profiles')) if root.tag == _q('dds') else None


def _with_transports(path: Path) -> Path | None:
    """A copy of profile ``path`` whose default participant has the large-image transports
    (and our log section, when it has none); None when it has transports of its own or is not
    a profile file that can be read."""
    try:
        text = path.read_bytes()
        root = ET.fromstring(text)
    except (OSError, ET.ParseError):
        return None
    profiles = _profiles(root)
    participant = None if profiles is None else next(
        (p for p in profiles.iter(_q('participant')) if p.get('is_default_profile') == 'true'),
        None)
    if participant is None:
        return None
    rtps = participant.find(_q('rtps'))
    if rtps is None:
        rtps = ET.SubElement(participant, _q('rtps'))
    if any(rtps.find(_q(tag)) is not None for tag in TRANSPORT_TAGS):
        return None
    ours_root = ET.parse(large_data_profile()).getroot()
    ours = _profiles(ours_root)
    descriptors = profiles.find(_q('transport_descriptors'))
    if descriptors is None:
        descriptors = ET.Element(_q('transport_descriptors'))
        profiles.insert(0, descriptors)
    descriptors.extend(ours.find(_q('transport_descriptors')))
    our_rtps = next(ours.iter(_q('participant'))).find(_q('rtps'))
    rtps.extend(our_rtps.find(_q(tag)) for tag in TRANSPORT_TAGS)
    if root is profiles:
        root = ET.Element(_q('dds'))
        root.append(profiles)
    if root.find(_q('log')) is None:
        root.insert(0, ours_root.find(_q('log')))
    ET.register_namespace('', NS)
    merged = ET.tostring(root, encoding='utf-8', xml_declaration=True)
    digest = hashlib.sha256(merged).hexdigest()[:16]
    out = Path(tempfile.gettempdir()) / 'cobot_calib_fastdds' / f'{path.stem}_{digest}.xml'
    if not out.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_suffix(f'.{os.getpid()}.tmp')
        tmp.write_bytes(merged)
        tmp.replace(out)
    return out
