"""`cobot-calib trial` and `cobot-calib experiment user-frame`: repeatability trials over ROS.

The experiment reproduces the first paper's comparison (Tables 4-5, Figures 2-4) on the mock
robot: a reference trial and one trial per calibration method, each n cycles over P1..P5 of
the chosen set-up, then one table and one box plot.
"""
from __future__ import annotations

import functools
import json
from pathlib import Path
import sys
import time

from cobot_calib_ros import paths
from cobot_calib_ros.api import launcher, report
from cobot_calib_ros.cli import demo
from cobot_calib_ros.store.trials import TrialStore

EXPERIMENT_METHODS = ('reference', 'three_point', 'five_point_lsq', 'rigid')


class TrialClient:
    """Sends run_trial goals and prints the feedback (one rclpy node)."""

    def __init__(self, say) -> None:
        import rclpy
        from rclpy.action import ActionClient
        from cobot_calib_msgs.action import RunTrial
        rclpy.init()
        self.node = rclpy.create_node('cobot_calib_trial_client')
        self.RunTrial = RunTrial
        self._client = ActionClient(self.node, RunTrial, 'run_trial')
        self._say = say

    def close(self) -> None:
        import rclpy
        self.node.destroy_node()
        rclpy.try_shutdown()

    def run(self, method: str, axis: str, cycles: int, trial_id: str = '',
            layout: str = '', timeout: float = 3600.0):
        from cobot_calib_ros.api.client import run_action
        goal = self.RunTrial.Goal(trial_id=trial_id, method=method, axis=axis,
                                  cycles=cycles, layout=layout)
        last = [-1]

        def feedback(msg) -> None:
            fb = msg.feedback
            if fb.statistics.cycles_done != last[0] and fb.statistics.cycles_done >= 2:
                last[0] = fb.statistics.cycles_done
                s = fb.statistics
                self._say(f'  {method}: cycle {s.cycles_done}/{s.cycles_total}  '
                          f'RP_all {s.rp_all_mm:.4f} mm')
        _, result = run_action(self.node, self._client, goal, timeout, feedback)
        return result


def run_trial(args) -> int:
    """`cobot-calib trial`: one trial on a running suite."""
    from cobot_calib_ros.api.client import CallError
    say = functools.partial(demo.say, args)
    client = TrialClient(say)
    try:
        result = client.run(args.method, args.axis, args.cycles, args.trial_id)
    except CallError as e:
        print(f'trial failed: {e}', file=sys.stderr)
        return 1
    finally:
        client.close()
    if result.error_code != 0:
        print(f'trial {result.trial_id} failed: {result.message}', file=sys.stderr)
        return 1
    out = {'trial_id': result.trial_id, 'message': result.message,
           'rp_mm': list(result.statistics.rp_mm), 'rp_all_mm': result.statistics.rp_all_mm,
           'csv': result.csv_path}
    print(json.dumps(out) if args.json else
          f'trial {result.trial_id}: {result.message}\n  data: {result.csv_path}')
    return 0


def run_experiment(args) -> int:
    """`cobot-calib experiment user-frame`: reference + each method, one table, one figure."""
    from cobot_calib_ros.api.client import CallError, wait_for_suite
    say = functools.partial(demo.say, args)
    data_dir = paths.data_dir(args.data_dir)
    stamp = time.strftime('%Y%m%dT%H%M%S')
    overrides = {n: {'layout': args.setup} for n in ('mock_robot', 'repeatability_trial')}
    overrides['repeatability_trial']['data_dir'] = str(data_dir)
    rows, trial_ids = [], []
    try:
        with launcher.private_suite(args.cell, overrides, say):
            client = TrialClient(say)
            try:
                wait_for_suite(client.node)
                for method in EXPERIMENT_METHODS:
                    trial_id = f'{stamp}-{args.setup}-{args.axis}-{method}'
                    say(f'{method}: {args.cycles} cycles on the {args.setup} set-up ...')
                    result = client.run(method, args.axis, args.cycles, trial_id, args.setup)
                    if result.error_code != 0:
                        raise RuntimeError(f'{method} trial failed: {result.message}')
                    trial_ids.append(trial_id)
                    rows.append({'method': method, 'trial_id': trial_id,
                                 'rp_mm': list(result.statistics.rp_mm),
                                 'rp_all_mm': result.statistics.rp_all_mm})
            finally:
                client.close()
    except (CallError, RuntimeError) as e:
        print(f'experiment failed: {e}', file=sys.stderr)
        return 1
    png, table_file, table = report.write_report(TrialStore(data_dir), trial_ids,
                                                 _report_dir(args, data_dir))
    if args.json:
        print(json.dumps({'setup': args.setup, 'axis': args.axis, 'cycles': args.cycles,
                          'rows': rows, 'figure': str(png), 'table': str(table_file)}))
    else:
        print(f'\n{table}\nfigure: {png}\ntable:  {table_file}')
    return 0


def run_report(args) -> int:
    """`cobot-calib report TRIAL...`: PNG box plot and the paper's table for stored trials."""
    data_dir = paths.data_dir(args.data_dir)
    try:
        png, table_file, table = report.write_report(TrialStore(data_dir), args.trials,
                                                     _report_dir(args, data_dir))
    except ValueError as e:
        print(f'report failed: {e}', file=sys.stderr)
        return 1
    print(f'{table}\nfigure: {png}\ntable:  {table_file}')
    return 0


def _report_dir(args, data_dir: Path) -> Path:
    """--out, else <data dir>/reports."""
    return Path(args.out) if args.out else data_dir / 'reports'
