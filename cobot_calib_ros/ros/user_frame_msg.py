"""A stored user-frame calibration (store.records.UserFrameRecord as a dict) as the
UserFrameCalibration message user_frame_solver latches, answers and lists: the message schema,
kept out of the node."""
from __future__ import annotations

from cobot_calib_msgs.msg import PointResidual, SurfaceModel as SurfaceMsg, UserFrameCalibration
import numpy as np

from cobot_calib_ros.ros import convert
from cobot_calib_ros.ros.time import ns_to_stamp


def record_to_msg(record: dict) -> UserFrameCalibration:
    r = record['result']
    inputs = record['inputs']
    msg = UserFrameCalibration(id=record['id'], method=record['method'],
                               kinematics=record.get('kinematics', ''))
    msg.stamp = ns_to_stamp(record['stamp_ns'])
    msg.transform = convert.matrix_to_transform(
        np.array(r['T_base_user']), record['base_frame'], record['user_frame'], msg.stamp)
    msg.matrix = [float(v) for v in np.ravel(r['M'])]
    outliers = set(r['outliers'])
    for i, (name, pu, pb, res) in enumerate(zip(inputs['point_names'], inputs['points_user'],
                                                inputs['points_base'], r['residuals'])):
        [pu_msg], [pb_msg] = convert.array_to_points([pu]), convert.array_to_points([pb])
        pr = PointResidual(name=name, point_user=pu_msg, point_base=pb_msg,
                           residual_norm=float(np.linalg.norm(res)), outlier=i in outliers)
        pr.residual.x, pr.residual.y, pr.residual.z = (float(v) for v in res)
        msg.residuals.append(pr)
    msg.rms_residual, msg.max_residual = float(r['rms']), float(r['max_residual'])
    msg.condition_number, msg.collinearity = float(r['condition_number']), float(r['collinearity'])
    msg.covariance = [float(v) for v in np.ravel(r['covariance'])]
    msg.scale_x, msg.scale_y, msg.scale_z = (float(v) for v in r['scale'])
    msg.shear_xy, msg.shear_xz, msg.shear_yz = (float(v) for v in r['shear'])
    s = r.get('surface')
    if s:
        msg.surface = SurfaceMsg(valid=bool(s['valid']), powers_x=list(s['powers_x']),
                                 powers_y=list(s['powers_y']),
                                 coefficients=[float(c) for c in s['coefficients']],
                                 rms_before=float(s['rms_before']),
                                 rms_after=float(s['rms_after']))
    return msg
