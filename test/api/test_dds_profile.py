"""api.dds_profile: every process the product starts gets shared-memory segments that hold a
1 MB camera image, with the session's own Fast DDS profile (test/fastdds_no_lease_check.xml)
kept."""
import os
from pathlib import Path
import subprocess
import sys
import xml.etree.ElementTree as ET

from cobot_calib_ros.api.dds_profile import (large_data_env, large_data_profile, NS,
                                             PROFILE_ENV)

TESTS = Path(__file__).resolve().parents[1]
SEGMENT_BYTES = 16 * 2 ** 20
# the largest shared-memory segment this process mapped [bytes]: Fast DDS maps its own
# participant's segment (/dev/shm/fastrtps_<guid>) when the participant starts
MAPPED_SEGMENT = '''
import re, rclpy
rclpy.init()
node = rclpy.create_node('segment_probe')
sizes = [0]
for line in open('/proc/self/maps'):
    m = re.match(r'([0-9a-f]+)-([0-9a-f]+) .* /dev/shm/fastrtps_(?!port)', line)
    if m:
        sizes.append(int(m.group(2), 16) - int(m.group(1), 16))
print(max(sizes))
'''


def q(tag: str) -> str:
    return f'{{{NS}}}{tag}'


def segment_mapped(env: dict) -> int:
    out = subprocess.run([sys.executable, '-c', MAPPED_SEGMENT], env=env, capture_output=True,
                         text=True, timeout=60, check=True)
    return int(out.stdout.split()[-1])


def test_without_a_profile_the_product_profile_is_used():
    env = large_data_env({'PATH': '/bin'})
    assert env[PROFILE_ENV] == str(large_data_profile())
    assert env['PATH'] == '/bin'


def test_a_profile_without_transports_keeps_its_settings_and_gets_the_large_segment():
    given = TESTS / 'fastdds_no_lease_check.xml'
    merged = Path(large_data_env({PROFILE_ENV: str(given)})[PROFILE_ENV])
    assert merged != given and large_data_env({PROFILE_ENV: str(given)})[PROFILE_ENV] == \
        str(merged)                                 # written once, the same file again
    root = ET.parse(merged).getroot()
    participant = next(p for p in root.iter(q('participant'))
                       if p.get('is_default_profile') == 'true')
    assert participant.get('profile_name') == 'no_lease_check'
    assert participant.find(f'.//{q("leaseDuration")}/{q("sec")}').text == 'DURATION_INFINITY'
    assert participant.find(f'{q("rtps")}/{q("useBuiltinTransports")}').text == 'false'
    used = {t.text for t in participant.iter(q('transport_id'))}
    sizes = {d.find(q('transport_id')).text: d.find(q('segment_size'))
             for d in root.iter(q('transport_descriptor'))}
    assert used == set(sizes)
    assert [int(s.text) for s in sizes.values() if s is not None] == [SEGMENT_BYTES]
    consumer = root.find(f'{q("log")}/{q("consumer")}')          # Fast DDS's errors: stderr
    assert consumer.find(q('class')).text == 'StdoutErrConsumer'


def test_fast_dds_errors_go_to_stderr_not_stdout(tmp_path):
    """A Fast DDS error (here: a profile naming a transport it does not define) is printed on
    stderr with the product's log section, on stdout without it (Fast DDS's default), where it
    broke `--json` output and tests that read a process's stdout line by line."""
    ours = ET.parse(large_data_profile()).getroot()
    ET.register_namespace('', NS)
    for with_log in (True, False):
        root = ET.fromstring(ET.tostring(ours))
        if not with_log:
            root.remove(root.find(q('log')))
        ET.SubElement(next(root.iter(q('userTransports'))), q('transport_id')).text = 'undefined'
        profile = tmp_path / f'log_{with_log}.xml'
        profile.write_bytes(ET.tostring(root))
        out = subprocess.run([sys.executable, '-c', 'import rclpy; rclpy.init(); '
                              'rclpy.create_node("n"); print("created")'],
                             env=dict(os.environ, FASTRTPS_DEFAULT_PROFILES_FILE=str(profile)),
                             capture_output=True, text=True, timeout=60)
        error = 'Transport Node not found. Given ID: undefined'
        assert (error in out.stderr, error in out.stdout) == (with_log, not with_log), out
        assert out.stdout.splitlines()[-1] == 'created'


def test_a_profile_with_its_own_transports_is_left_alone(tmp_path):
    own = tmp_path / 'own.xml'
    own.write_text(f'''<profiles xmlns="{NS}"><participant profile_name="p"
        is_default_profile="true"><rtps><useBuiltinTransports>true</useBuiltinTransports>
        </rtps></participant></profiles>''')
    assert large_data_env({PROFILE_ENV: str(own)})[PROFILE_ENV] == str(own)
    broken = tmp_path / 'broken.xml'
    broken.write_text('<profiles')
    assert large_data_env({PROFILE_ENV: str(broken)})[PROFILE_ENV] == str(broken)


def test_fast_dds_takes_the_merged_profile_and_maps_the_large_segment():
    """The session's profile (conftest) merged: Fast DDS maps a 16 MB segment; the session's
    profile alone leaves its default (512 KB). The probe is alone on a domain of its own: a
    participant also maps the segments of the peers it discovers (another test's 16 MB)."""
    import domain_coordinator
    # the session's own profile: an in-process `cobot-calib` call of another test of this
    # worker has put the merged one into os.environ (cli.main does, as every command does)
    with domain_coordinator.domain_id() as domain:
        env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                   ROS_DOMAIN_ID=str(domain),
                   FASTRTPS_DEFAULT_PROFILES_FILE=str(TESTS / 'fastdds_no_lease_check.xml'))
        assert segment_mapped(large_data_env(env)) >= SEGMENT_BYTES
        assert 0 < segment_mapped(env) < 2 ** 20
