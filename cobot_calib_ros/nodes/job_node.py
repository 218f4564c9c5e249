"""The base of the nodes that run calibration jobs as actions (issue 30 item 5), and the cell
bootstrap (read_cell_setup: cell_file, layout, data_dir read once; the cell, its model, the cell
its results are stored under, its repository) that it and robot_adapter share.

What hand_eye_calibrator, kinematic_identifier, repeatability_trial and user_frame_solver each
wrote out: the bootstrap (``cell_file``, ``layout``, ``data_dir`` read once; the cell, its
kinematic model, the cell its results are stored under, its repository), the companion node the
job's calls to other nodes spin on, diagnostics, one job at a time (a goal is rejected while one
runs, and refused again if two raced past the check), and one way a goal ends (succeed, cancel
or abort with a cause, core.errors.ErrorCode, answered through ros/results; logged, the
diagnostics told). A node keeps its own parameters and its job's ``run``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import threading

import numpy as np
from rclpy.action import GoalResponse
from rclpy.node import Node

from cobot_calib_ros import paths, store
from cobot_calib_ros.core import frames
from cobot_calib_ros.core.kinematics import model_for
from cobot_calib_ros.loaders import load_cell
from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal
from cobot_calib_ros.ros import results, spin
from cobot_calib_ros.ros.diagnostics import Diagnostics, OK, WARN
from cobot_calib_ros.ros.params import read_once
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.rigs import rig_of


# -- the bootstrap every node of a cell repeats: JobNode's, robot_adapter's -------------------
DATA_DIR_DEFAULT = 'empty = $COBOT_CALIB_DATA or ~/.ros/cobot_calib'


@dataclass(frozen=True)
class CellSetup:
    cell: object            # core.cell.Cell
    model: object           # its kinematic model (core.kinematics.model_for)
    root: Path              # the data dir
    results_cell: ResultsCell

    def repository(self):
        """The results of this cell, opened afresh."""
        return store.open(self.root, cell=self.results_cell)


def read_cell_setup(node, *, cell_help: str, data_help: str,
                    layout_help: str | None = None) -> CellSetup:
    """Read ``cell_file``, ``layout`` (only when ``layout_help`` is given) and ``data_dir`` of
    ``node`` once and load its cell (CellFileError / ValueError as load_cell raises them)."""
    read_once(node, 'cell_file', paths.DEFAULT_CELL, cell_help)
    layout = read_once(node, 'layout', '', layout_help) if layout_help is not None else ''
    data_dir = read_once(node, 'data_dir', '', f'{data_help}; {DATA_DIR_DEFAULT}')
    cell = load_cell(paths.cell_file(node.get_parameter('cell_file').value), layout or None)
    return CellSetup(cell, model_for(cell), paths.data_dir(data_dir),
                     ResultsCell.of(cell, node.get_namespace()))


def parse_user_frame(text: str) -> np.ndarray | None:
    """``"x y z roll pitch yaw"`` [m, rad] -> T_base_user; None for ''; ValueError else."""
    if not text.strip():
        return None
    try:
        values = [float(v) for v in text.replace(',', ' ').split()]
    except ValueError:
        values = []
    if len(values) != 6 or not np.all(np.isfinite(values)):
        raise ValueError(f'user_frame must be "x y z roll pitch yaw" [m, rad], got {text!r}')
    return frames.from_xyz_rpy(values[:3], values[3:])


class JobNode(Node):
    """``job``: what a goal is called in messages ('a hand-eye calibration');
    ``cell_help`` / ``data_help``: the descriptions of the cell_file / data_dir parameters."""

    def __init__(self, name: str, *, job: str, cell_help: str, data_help: str,
                 layout_help: str = 'Marker layout; empty = the cell default',
                 **kwargs) -> None:
        super().__init__(name, **kwargs)
        self._job_name = job
        self._setup = read_cell_setup(self, cell_help=cell_help, data_help=data_help,
                                      layout_help=layout_help)
        self._cell, self._model = self._setup.cell, self._setup.model
        self._root, self._results_cell = self._setup.root, self._setup.results_cell
        self._answers = spin.Companion(self, 'clients')
        self._busy = threading.Lock()
        self._health = Diagnostics(self)

    def destroy_node(self):
        self._answers.destroy()
        return super().destroy_node()

    def _p(self, name: str):
        return self.get_parameter(name).value

    def _repository(self):
        """The results of this node's cell, opened afresh (another node may have stored since)."""
        return self._setup.repository()

    def _foreign(self, meta: dict) -> Failure | None:
        """None if a stored trial or collection (its metadata) is this cell's, or legacy
        (stored before they named their cell: on this robot or an unrecorded one), else a
        FOREIGN_RESULT Failure saying why not (store.cells)."""
        return self._results_cell.problem(meta.get('cell', ''), meta.get('robot', ''))

    def _rig(self, kinematics: str = 'latest'):
        """The cell's rig with the active results (store.rigs.rig_of; KeyError / ValueError)."""
        return rig_of(self._repository(), self._cell, kinematics, self._model)

    def _read_board_frame(self) -> None:
        """The ``user_frame`` parameter of a node that plans views of the cell's board (the
        board is given in the user frame): T_base_user, or the active user frame's."""
        read_once(self, 'user_frame', '', 'T_base_user as "x y z roll pitch yaw" [m, rad] to '
                  'plan the views; empty = the active user-frame calibration in data_dir')
        self._user_frame = parse_user_frame(self._p('user_frame'))

    def _T_base_user(self) -> np.ndarray:
        """Where the board's user frame is: the parameter's, else the active calibration's;
        ValueError saying what to do when there is neither."""
        if self._user_frame is not None:
            return self._user_frame
        try:
            return self._rig().T_base_user()
        except (KeyError, ValueError, Refusal):
            raise ValueError(f'no user frame to find the board by: cell {self._cell.name} has '
                             'no active one; calibrate it first (cobot-calib teach, or call '
                             'calibrate_user_frame) or set the user_frame parameter') from None

    def _accept(self, goal) -> GoalResponse:
        if self._busy.locked():
            self.get_logger().warning(f'goal rejected: {self._job_name} is running; wait '
                                      'for its end or cancel it')
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _exclusive(self, goal_handle, run, Result):
        """``run(goal_handle)`` holding the job lock: a goal that raced past _accept while
        another runs ends at once, BUSY."""
        if not self._busy.acquire(blocking=False):
            goal_handle.abort()
            return results.answer(Result(), ErrorCode.BUSY, f'{self._job_name} is running')
        try:
            return run(goal_handle)
        finally:
            self._busy.release()

    def _end(self, goal_handle, result, cause: ErrorCode, message: str):
        """The goal's end with ``cause``, answered in ``result`` through ros/results: SUCCESS
        succeeds, a cancelled goal is canceled, anything else is aborted; logged and told to
        the diagnostics."""
        results.answer(result, cause, message)
        if cause == ErrorCode.SUCCESS:
            goal_handle.succeed()
            spin.log_info(self.get_logger(), message)
        elif goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
            self.get_logger().warning(message)
        self._health.set(OK if cause == ErrorCode.SUCCESS else WARN, message)
        return result
