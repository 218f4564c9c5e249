from cobot_calib_ros.core.ids import record_id
from cobot_calib_ros.store.files import check_id


def test_a_record_id_is_utc_time_to_the_nanosecond_and_sorts_by_time():
    wall_ns = 1_795_000_000_123_456_789            # 2026-11-18 11:06:40.123456789 UTC
    assert record_id('rigid', wall_ns) == '20261118T110640.123456789Z-rigid'
    assert record_id('a', wall_ns) < record_id('a', wall_ns + 1)


def test_a_fresh_record_id_passes_the_stores_id_check():
    assert check_id(record_id('five_point_lsq')).endswith('Z-five_point_lsq')
