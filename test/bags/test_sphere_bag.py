"""bags/iiwa_spheres: a recorded sphere-coupling session gives back the identification the live
session made (issue 12's iiwa sample bag, issue 10's `identify --source BAG`)."""
import json
from pathlib import Path

from cobot_calib_ros.cli.main import main

BAG = Path(__file__).resolve().parents[2] / 'bags' / 'iiwa_spheres'


def test_identify_from_the_bag_reproduces_the_live_identification(capsys):
    expected = json.loads((BAG / 'expected.json').read_text())
    assert main(['identify', '--source', str(BAG), '--json']) == 0
    got = json.loads(capsys.readouterr().out)
    assert got['rows'] == 150 and got['source_kind'] == 'bag'
    # expected.json's parameters are the live session's as identified since issue 37 (zero
    # offsets first in the identifiability order, the prior around nominal: < 6e-8 from the
    # live recording's own values)
    assert [d['name'] for d in got['dropped']] == expected['dropped_parameters']
    assert [p['name'] for p in got['identified']] == [p['name'] for p in expected['identified']]
    for mine, live in zip(got['identified'], expected['identified']):
        assert abs(mine['value'] - live['value']) <= 1e-9, mine['name']
    # spheres see no base, the coupling is one point on the tool (issue 37.5)
    assert {u['name']: u['affects'] for u in got['unseen']} == {
        'alpha_1': 'base', 'a_1': 'base', 'theta_1': 'base', 'd_1': 'base', 'theta_7': 'tool',
        'd_7': 'tool'}
    # issue 23.11: each parameter's nominal beside it, from the cell's model and coupling
    import numpy as np
    from cobot_calib_ros.core.kinematics import model_for
    from cobot_calib_ros.core.kinematics.identification.parameters import ParameterSet
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    cell = load_cell(cell_file('iiwa7_close'))
    model = model_for(cell)
    names = [p['name'] for p in got['identified']]
    nominal = ParameterSet(model, names).values(model.nominal,
                                                cell.spheres.T_flange_coupling[:3, 3])
    np.testing.assert_array_equal([p['nominal'] for p in got['identified']], nominal)
    deviation = np.array([p['value'] - p['nominal'] for p in got['identified']])
    assert 0.0 < np.abs(deviation).max() < 0.01          # identified near nominal, not equal


def test_a_bag_without_sphere_captures_is_refused(capsys):
    teach = BAG.parent / 'five_point_close'
    assert main(['identify', '--source', str(teach)]) == 1
    assert 'no /cobot_calib/captures poses on the spheres' in capsys.readouterr().err


def test_the_identify_kinematics_goal_takes_the_bag_too(bag_domain, tmp_path):
    """The node's `file` may name a bag: kinematic_identifier (iiwa7 cell, its own process)
    identifies from the recorded captures and gives the live parameters again."""
    import rclpy
    from cobot_calib_ros.ros.action_client import ActionClient
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from cobot_calib_msgs.action import IdentifyKinematics
    from cobot_calib_ros.api import launcher
    from cobot_calib_ros.ros.calls import run_action
    expected = json.loads((BAG / 'expected.json').read_text())
    domain, env = bag_domain
    suite = launcher.Suite(tmp_path / 'logs')
    suite.start(launcher.suite_specs('iiwa7_close', ('kinematic_identifier',), overrides={
        'kinematic_identifier': {'data_dir': str(tmp_path / 'data')}}), env=env)
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node('test_identify_bag', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    client = ActionClient(node, IdentifyKinematics, 'identify_kinematics')
    try:
        _, result = run_action(node, client, IdentifyKinematics.Goal(
            file=str(BAG), dry_run=True), 120.0, executor=executor)
        missing = run_action(node, client, IdentifyKinematics.Goal(
            file=str(BAG.parent / 'five_point_close'), dry_run=True), 60.0,
            executor=executor)[1]
    finally:
        client.destroy()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        codes = suite.stop()
    assert result.error_code == IdentifyKinematics.Result.SUCCESS, result.message
    assert not result.calibration_id                        # dry run: nothing stored
    live = {p['name']: p['value'] for p in expected['identified']}
    got = dict(zip(result.parameter_names, result.values))
    assert set(got) == set(live)
    assert max(abs(got[n] - live[n]) for n in live) <= 2e-7     # the prior (issue 37)
    assert missing.error_code != IdentifyKinematics.Result.SUCCESS
    assert 'no /cobot_calib/captures poses on the spheres' in missing.message
    assert all(c == 0 for c in codes.values()), codes
