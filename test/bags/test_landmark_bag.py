"""bags/landmark_multi_close: a recorded landmark_multi session with the wrist camera's images
gives back its user frame (issue 12's landmark sample bag). The images go through a
landmark_detector (own domain, sim time), every view mark is paired with its landmarks as the
live solver pairs them, and the core fits the frame again (the replay that passes runs through
the CLI: test_sample_bags.py); a changed expected.yaml is caught."""
from pathlib import Path
import shutil

import numpy as np
import yaml

from cobot_calib_ros.api import replay_landmark_check as check
from cobot_calib_ros.core.errors import ErrorCode
from cobot_calib_ros.bags.reader import open_bag
from cobot_calib_ros.ros.time import header_ns

SAMPLE = Path(__file__).resolve().parents[2] / 'bags' / 'landmark_multi_close'


def test_sample_bag_is_light_and_complete():
    size = sum(p.stat().st_size for p in SAMPLE.iterdir())
    assert size < 4_000_000, size
    _, expected = check.read_expected(SAMPLE)
    with open_bag(SAMPLE) as bag:
        assert set(bag.topics) == {check.IMAGE_TOPIC, check.INFO_TOPIC, check.MARKS_TOPIC,
                                   check.USER_FRAME_TOPIC}
        assert check.is_landmark_bag(bag)
        marks = [bag.deserialize(m.rawdata, m.msgtype) for m in bag.messages([check.MARKS_TOPIC])]
        images = {header_ns(bag.deserialize(m.rawdata, m.msgtype))
                  for m in bag.messages([check.IMAGE_TOPIC])}
        [frame] = [bag.deserialize(m.rawdata, m.msgtype)
                   for m in bag.messages([check.USER_FRAME_TOPIC])]
    assert len(marks) == len(expected['views']) == 18
    assert {v['image_stamp_ns'] for v in expected['views']} <= images
    assert frame.id == expected['calibration_id']
    assert np.array_equal(np.reshape(frame.matrix, (4, 4)), expected['T_base_user'])


def test_tampered_expected_fails(tmp_path):
    bag = tmp_path / SAMPLE.name
    shutil.copytree(SAMPLE, bag)
    path = bag / check.EXPECTED_FILE
    data = yaml.safe_load(path.read_text())
    data['T_base_user'][0][3] += 5e-6          # 5 um off in x
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    result = check.check(str(bag))
    report = result.report
    print(report)
    assert not result and result.code == ErrorCode.IMPLAUSIBLE_FIT
    assert 'translation differs by 5.0' in report, report
    assert 'expected:' in report
