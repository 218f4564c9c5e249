"""ros.results: each interface's table maps every cause (core.errors.ErrorCode) to one of its own
result constants, and every result constant of the interface is some cause's answer."""
from __future__ import annotations

from pathlib import Path
import re

import pytest
from cobot_calib_msgs.action import MoveTo
from cobot_calib_msgs.srv import CalibrateUserFrame

from cobot_calib_ros.core.errors import ErrorCode, Failure
from cobot_calib_ros.ros import results

MSG_DEFS = Path(__file__).resolve().parents[2] / 'msg_defs'


def result_constants(path: Path) -> dict[str, int]:
    """The integer constants of a .srv response / .action result section."""
    section = path.read_text().split('---')[1]
    return {name: int(value)
            for name, value in re.findall(r'^u?int\d+ ([A-Z_]+)=(\d+)', section, re.MULTILINE)}


INTERFACES = {path.stem: result_constants(path)
              for path in sorted([*MSG_DEFS.glob('srv/*.srv'), *MSG_DEFS.glob('action/*.action')])
              if 'SUCCESS' in result_constants(path)}


def test_every_interface_with_result_codes_has_a_table() -> None:
    assert set(results.TABLES) == set(INTERFACES)
    assert len(INTERFACES) == 14


@pytest.mark.parametrize('interface', sorted(INTERFACES))
def test_the_table_covers_every_cause_and_every_constant(interface: str) -> None:
    constants = INTERFACES[interface]
    table = results.TABLES[interface]
    answers = {cause: results.code(interface, cause) for cause in ErrorCode}
    assert set(answers.values()) == set(constants.values()), (interface, answers)
    assert answers[ErrorCode.SUCCESS] == constants['SUCCESS'] == 0
    assert [c for c, v in answers.items() if v == 0] == [ErrorCode.SUCCESS]
    for cause, name in table.names.items():      # the name is the constant's own
        assert constants[name] == answers[cause]


def test_calibrate_user_frame_keeps_the_causes_numbers() -> None:
    for cause in ErrorCode:
        if cause.name in INTERFACES['CalibrateUserFrame']:
            assert results.code('CalibrateUserFrame', cause) == int(cause)


def test_fill_sets_the_interfaces_constant_and_the_message() -> None:
    result = results.fill(MoveTo.Result(), 'MoveTo',
                          Failure(ErrorCode.MOTION_FAILED, 'no IK solution'))
    assert result.error_code == MoveTo.Result.UNREACHABLE and result.message == 'no IK solution'
    response = results.fill(CalibrateUserFrame.Response(), 'CalibrateUserFrame',
                            Failure(ErrorCode.CANCELED, 'cancelled'))
    assert response.error_code == CalibrateUserFrame.Response.CAPTURE_FAILED


def test_answer_takes_a_cause_and_finds_the_interface_by_the_message() -> None:
    result = results.answer(MoveTo.Result(), ErrorCode.CANCELED, 'canceled')
    assert result.error_code == MoveTo.Result.CANCELED and result.message == 'canceled'
    assert results.interface_of(MoveTo.Result) == 'MoveTo'
    with pytest.raises(TypeError, match='ErrorCode'):
        results.answer(MoveTo.Result(), MoveTo.Result.CANCELED, 'an interface constant')


def test_disk_and_permission_errors_are_their_own_answer() -> None:
    """STORAGE_FAILED reaches every job's client as a constant of its own (a trial's was
    answered as INVALID_INPUT / MOTION_FAILED before issue 39)."""
    for interface in ('RunTrial', 'CalibrateTcp', 'CalibrateHandEye', 'CalibrateIntrinsics',
                      'CollectSphereData', 'IdentifyKinematics', 'CalibrateUserFrame',
                      'SetActiveCalibration'):
        assert results.TABLES[interface].names[ErrorCode.STORAGE_FAILED] == 'STORAGE_FAILED'
