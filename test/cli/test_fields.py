"""YAML values -> message fields (`cobot-calib call`): converted in Python to each field's
type, or refused with the field path; nothing unfit reaches the C setters."""
import math

from cobot_calib_msgs.msg import SurfaceModel, UserFrameCalibration
from cobot_calib_msgs.srv import (
    CalibrateUserFrame, CaptureJoints, ConvertPoints, GetGroundTruth, ListCalibrations)
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosidl_parser import definition as d
import yaml

from cobot_calib_ros.ros.fields import FieldError, set_fields


def _fill(msg_type, text: str):
    """set_fields from YAML text, then a trip through the C serializer and back."""
    msg = set_fields(msg_type(), yaml.safe_load(text))
    return deserialize_message(serialize_message(msg), msg_type)


def _refused(msg_type, text: str) -> str:
    with pytest.raises(FieldError) as e:
        set_fields(msg_type(), yaml.safe_load(text))
    return str(e.value)


@pytest.mark.parametrize('text, value', [
    ('{duration: 1}', 1.0), ('{duration: 0.2e0}', 0.2), ('{duration: 1e9}', 1e9),
    ('{duration: 1.0e9}', 1e9),
    ('{duration: -2.5E-3}', -2.5e-3), ('{duration: "0.5"}', 0.5), ('{duration: 0.5}', 0.5)])
def test_numbers_become_floats_for_float_fields(text, value):
    request = set_fields(CaptureJoints.Request(), yaml.safe_load(text))
    assert type(request.duration) is float and request.duration == value
    assert _fill(CaptureJoints.Request, text).duration == value


@pytest.mark.parametrize('word, check', [
    ('nan', math.isnan), ('.nan', math.isnan), ('NaN', math.isnan),
    ('inf', lambda v: v == math.inf), ('.inf', lambda v: v == math.inf),
    ('-inf', lambda v: v == -math.inf), ('-.inf', lambda v: v == -math.inf)])
def test_nan_and_inf_words_are_floats_not_garbage(word, check):
    point = _fill(ConvertPoints.Request, f'{{points: [{{x: {word}, y: 0, z: 0}}]}}').points[0]
    assert check(point.x)


def test_points_given_as_ints_keep_their_values():
    request = _fill(ConvertPoints.Request, '{points: [{x: 1, y: 2, z: 3}, {x: -4}]}')
    assert [(p.x, p.y, p.z) for p in request.points] == [(1.0, 2.0, 3.0), (-4.0, 0.0, 0.0)]


def test_nested_messages_sequences_strings_and_bools():
    request = _fill(CalibrateUserFrame.Request,
                    '{method: rigid, fit_surface: true, point_names: [P1, 2], '
                    'points_user: [{x: 0, y: 0, z: 0}], '
                    'points_base: [{x: 0.5, y: 1e-3, z: .nan}]}')
    assert request.method == 'rigid' and request.fit_surface is True
    assert list(request.point_names) == ['P1', '2']
    assert request.points_base[0].y == 1e-3 and math.isnan(request.points_base[0].z)
    response = _fill(GetGroundTruth.Response,
                     '{user_frame: {header: {frame_id: base, stamp: {sec: 3}}, '
                     'transform: {translation: {x: 1}, rotation: {w: 1}}}, '
                     'nominal_parameters: [1, 2.5, "3e-3"]}')
    assert response.user_frame.header.stamp.sec == 3
    assert response.user_frame.transform.translation.x == 1.0
    assert list(response.nominal_parameters) == [1.0, 2.5, 3e-3]


def test_fixed_arrays_and_integer_sequences():
    msg = _fill(UserFrameCalibration, f'{{matrix: {[1, 0, 0, 0, 0, 1, 0, 0] * 2}}}')
    assert list(msg.matrix) == [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0] * 2
    surface = _fill(SurfaceModel, '{valid: 1, powers_x: [0, 1, 2.0, "3"]}')
    assert surface.valid is True and list(surface.powers_x) == [0, 1, 2, 3]
    assert _fill(ListCalibrations.Request, '{max_count: 4294967295}').max_count == 2 ** 32 - 1


@pytest.mark.parametrize('msg_type, text, message', [
    (ConvertPoints.Request, '{points: [{x: abc, y: 2, z: 3}]}',
     "points[0].x: expected a float, got 'abc'"),
    (ConvertPoints.Request, '{points: [{x: 1}, {y: [1]}]}',
     'points[1].y: expected a float, got [1]'),
    (ConvertPoints.Request, '{points: [{w: 1}]}',
     'points[0].w: no such field; Point has: x, y, z'),
    (ConvertPoints.Request, '{points: {x: 1}}',
     "points: expected a list like [1, 2], got {'x': 1}"),
    (ConvertPoints.Request, '{points: [3]}', 'points[0]: expected a mapping of Point fields'),
    (ConvertPoints.Request, '{apply_surface: maybe}', 'apply_surface: expected true or false'),
    (ConvertPoints.Request, '{calibration_id: [a]}',
     "calibration_id: expected a string, got ['a']"),
    (CaptureJoints.Request, '{duration: }', 'duration: expected a float, got null'),
    (CaptureJoints.Request, '{duration: true}', 'duration: expected a float, got True'),
    (CaptureJoints.Request, '{duration: 0.5 s}', "duration: expected a float, got '0.5 s'"),
    (CaptureJoints.Request, '{durations: 1}', 'durations: no such field; CaptureJoints request '
                                              'has: duration, start'),
    (CaptureJoints.Request, '[1, 2]', 'request: expected a mapping of CaptureJoints request'),
    (ListCalibrations.Request, '{max_count: -1}',
     'max_count: expected a uint32 in [0, 4294967295], got -1'),
    (ListCalibrations.Request, '{max_count: 1.5}', 'max_count: expected an integer, got 1.5'),
    (SurfaceModel, '{powers_x: [1, 256]}', 'powers_x[1]: expected a uint8 in [0, 255], got 256'),
    (UserFrameCalibration, '{matrix: [1, 2]}', 'matrix: expected exactly 16 values, got 2'),
    (GetGroundTruth.Response, '{user_frame: {header: {stamp: {sec: 2147483648}}}}',
     'user_frame.header.stamp.sec: expected a int32 in'),
])
def test_unfit_values_are_refused_with_the_field_path(msg_type, text, message):
    assert _refused(msg_type, text).startswith(message)


def test_an_empty_argument_is_a_default_request():
    assert set_fields(CaptureJoints.Request(), None).duration == 0.0


class _Bounded:
    """A message with a bounded string and sequence and a float32 (none in our packages)."""

    SLOT_TYPES = (d.BoundedString(4), d.BoundedSequence(d.BasicType('double'), 2),
                  d.BasicType('float'), d.BasicType('octet'))

    @classmethod
    def get_fields_and_field_types(cls):
        return {'name': 'string<=4', 'values': 'sequence<double, 2>', 'gain': 'float',
                'flag': 'octet'}


def test_bounded_strings_and_sequences_float32_and_octets():
    msg = set_fields(_Bounded(), {'name': 'abcd', 'values': [1, '2'], 'gain': 3, 'flag': 7})
    assert (msg.name, msg.values, msg.gain, msg.flag) == ('abcd', [1.0, 2.0], 3.0, b'\x07')
    assert str(_refused_bounded({'name': 'abcde'})) == (
        'name: expected at most 4 characters, got 5')
    assert str(_refused_bounded({'values': [1, 2, 3]})) == (
        'values: expected at most 2 values, got 3')
    assert str(_refused_bounded({'gain': 1e39})).startswith('gain: expected a float32')


def _refused_bounded(values: dict) -> FieldError:
    with pytest.raises(FieldError) as e:
        set_fields(_Bounded(), values)
    return e.value
