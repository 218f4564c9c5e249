"""core.provenance: the one line a stale result is reported in, and the note of a calibration
started before its prerequisites (issue 36.2, 36.3)."""
from cobot_calib_ros.core.provenance import missing_prerequisites, Stale


def test_a_stale_result_is_one_line_naming_both_ids_and_the_change():
    assert Stale('user_frame', 'F', 'tcp', 't1', 't2', change_mm=0.1,
                 where='at the tool').line() == (
        'user frame F was touched with TCP t1; the active TCP t2 is 0.100 mm away at the tool: '
        'touch the frame again, or keep it')
    assert Stale('hand_eye', 'h1', 'kinematics', 'nominal', 'k1', change_mm=0.0123,
                 where='at the flange over its 12 poses').line() == (
        'hand-eye h1 was measured with kinematics nominal; the active kinematics k1 is 0.012 '
        'mm away at the flange over its 12 poses: calibrate the hand-eye again, or keep it')
    assert Stale('tcp', 't1', 'kinematics', 'k0', 'k1').line().endswith(
        'the active kinematics k1 differs by an amount not known here: calibrate the TCP '
        'again, or keep it')
    as_json = Stale('hand_eye', 'h1', 'intrinsics', 'nominal', 'i1', change_px=1.5).to_dict()
    assert as_json['change_px'] == 1.5 and as_json['message'].startswith('hand-eye h1 was')


def test_a_calibration_before_its_prerequisites_names_them():
    assert missing_prerequisites('the TCP is', {'kinematics': 'k1'}) == ''
    assert missing_prerequisites('the user frame is', {
        'kinematics': 'nominal', 'hand_eye': 'h1', 'intrinsics': 'nominal'}) == (
        'the user frame is measured through the nominal kinematics and intrinsics (none '
        'calibrated is active): calibrate them first for a result consistent with the '
        'calibrated cell')
