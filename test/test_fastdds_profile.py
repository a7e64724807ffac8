"""
The nodes' Fast DDS profile: named unless one is, read back for the recorder's drain, loaded.

What the profile buys is measured where it acts: the lock-step recorder that is paused
mid-run keeps every message with a drain of the profile's heartbeat and half a second
(test_nodes), and the suite's DDS tests start in a third of the time.
"""

import os
from pathlib import Path
import subprocess
import sys
import xml.etree.ElementTree as ET

import pytest
from ros_ehs.nodes.fastdds_profile import (ENV, FASTDDS_HEARTBEAT, heartbeat_period, PROFILE,
                                           use_profile)

RT = Path(__file__).resolve().parents[1] / 'launch_scripts' / 'fastdds_rt.xml'


def test_the_profile_is_named_unless_one_is():
    env = {}
    assert use_profile(env) == str(PROFILE) and env[ENV] == str(PROFILE)
    env = {ENV: '/etc/mine.xml'}
    assert use_profile(env) == '/etc/mine.xml' and env[ENV] == '/etc/mine.xml'
    env = {ENV: ''}                                 # set but empty: Fast DDS reads none
    assert use_profile(env) == str(PROFILE)


def test_the_heartbeat_is_read_from_the_profile_in_effect(tmp_path):
    assert heartbeat_period({ENV: str(PROFILE)}) == pytest.approx(0.1)
    assert heartbeat_period({ENV: str(RT)}) == pytest.approx(0.1)
    assert heartbeat_period({}) == FASTDDS_HEARTBEAT == 3.0         # Fast DDS's own
    assert heartbeat_period({ENV: str(tmp_path / 'missing.xml')}) == FASTDDS_HEARTBEAT
    bad = tmp_path / 'bad.xml'
    bad.write_text('<profiles><data_writer')
    assert heartbeat_period({ENV: str(bad)}) == FASTDDS_HEARTBEAT
    mine = tmp_path / 'mine.xml'
    mine.write_text(
        '<?xml version="1.0"?><profiles xmlns="http://www.eprosima.com/XMLSchemas/'
        'fastRTPS_Profiles"><data_writer profile_name="w" is_default_profile="false"><times>'
        '<heartbeatPeriod><sec>9</sec></heartbeatPeriod></times></data_writer>'
        '<data_writer profile_name="d" is_default_profile="true"><times><heartbeatPeriod>'
        '<sec>1</sec><nanosec>500000000</nanosec></heartbeatPeriod></times></data_writer>'
        '</profiles>')
    assert heartbeat_period({ENV: str(mine)}) == pytest.approx(1.5)   # the default writer's
    plain = tmp_path / 'plain.xml'                  # no namespace: Fast DDS reads it too
    plain.write_text('<profiles><data_writer profile_name="d" is_default_profile="true">'
                     '<times><heartbeatPeriod><nanosec>250000000</nanosec></heartbeatPeriod>'
                     '</times></data_writer></profiles>')
    assert heartbeat_period({ENV: str(plain)}) == pytest.approx(0.25)


def _settings(path):
    """Return the discovery settings and the writers' times of a profile, as text."""
    root = ET.parse(path).getroot()
    disc = root.find('.//{*}discovery_config')
    times = root.find('.//{*}data_writer/{*}times')
    return ET.tostring(disc), ET.tostring(times)


def test_the_real_time_profile_discovers_and_beats_as_the_package_profile():
    assert _settings(RT) == _settings(PROFILE)


@pytest.mark.ros
@pytest.mark.parametrize('profile', [PROFILE, RT])
def test_fast_dds_loads_each_profile_without_a_word(profile):
    """A participant made under each profile (Fast DDS prints a refused one's error)."""
    env = dict(os.environ, **{ENV: str(profile)}, ROS_DOMAIN_ID='231',
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    code = ('import rclpy; rclpy.init(); n = rclpy.create_node("profile_probe"); '
            'n.create_publisher(__import__("std_msgs.msg").msg.String, "probe", 10); '
            'print("up", flush=True); n.destroy_node(); rclpy.shutdown()')
    p = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 0 and p.stdout.strip() == 'up', p.stderr
    assert 'XML' not in p.stderr and 'rror' not in p.stderr, p.stderr
