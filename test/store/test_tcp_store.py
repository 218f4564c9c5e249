"""TCP records (store.records.TcpRecord) in the folder store, SQLite and PostgreSQL alike:
keyed by cell, one active per tool, a rejected one kept but never active; the record reads
back as it was written."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from cobot_calib_ros import store
from cobot_calib_ros.core import frames
from cobot_calib_ros.core.tcp import solve_tcp
from cobot_calib_ros.core.tcp.touches import plan_touches
from cobot_calib_ros.store.cells import ResultsCell
from cobot_calib_ros.store.repository import FolderRepository
from cobot_calib_ros.store.records import TcpRecord

T_FLANGE_TOOL = frames.from_xyz_rpy([0.0003, -0.0002, 0.1004], [0.0, 0.0, 0.0])
_plants = itertools.count()


def _record(tool: str, stamp_ns: int, gate_problem: str = '', dz: float = 0.0) -> dict:
    T = T_FLANGE_TOOL.copy()
    T[2, 3] += dz
    plan = plan_touches('P1', 4)
    flange = np.array([frames.make_transform(R, [0.5, 0.1, 0.1]) @ frames.invert(T)
                       for R in plan.orientations])
    solution = solve_tcp(flange)
    record = TcpRecord.from_solution(
        solution, tool, 'P1', [label for label, _ in plan.steps()], np.zeros((4, 7)), flange,
        stamp_ns, tilt=0.52, gate_problem=gate_problem).to_dict()
    record['id'] = f'tcp-{tool}-{stamp_ns}'
    return record


@pytest.fixture(params=['folder', 'sqlite', 'postgresql'])
def repo(request, tmp_path):
    cell = ResultsCell(f'tcp_cell_{next(_plants)}_{id(request)}', 'sawyer')
    if request.param == 'folder':
        (tmp_path / 'calibrations').mkdir()
        return FolderRepository(tmp_path, cell)
    url = (f'sqlite:///{tmp_path / "results.sqlite"}' if request.param == 'sqlite'
           else request.getfixturevalue('postgres_url'))
    return store.open(tmp_path, url, cell)


def test_one_tcp_is_active_per_tool_and_a_rejected_one_never(repo):
    assert repo.tcp.save_and_activate(_record('tool0', 1))
    assert repo.tcp.save_and_activate(_record('gripper', 2, dz=0.05))
    outcome = repo.tcp.save_and_activate(_record('tool0', 3, 'residual 0.4 mm per axis'))
    assert not outcome and 'residual 0.4 mm' in outcome.reason
    assert repo.tcp.active('tool0')['id'] == 'tcp-tool0-1'
    assert repo.tcp.active('gripper')['id'] == 'tcp-gripper-2'
    assert list(repo.tcp.rejected()) == ['tcp-tool0-3']
    assert repo.tcp.save_and_activate(_record('tool0', 4, dz=1e-4))
    again = _reopen(repo)
    active = again.tcp.active('tool0')
    assert active['id'] == 'tcp-tool0-4' and active['cell'] == repo.cell.name
    assert [r['id'] for r in again.tcp.history()][-1] == 'tcp-tool0-1'
    assert repo.cell.name in again.cells()


def _reopen(repo):
    """The same repository opened again (what another process sees)."""
    if isinstance(repo, FolderRepository):
        return FolderRepository(repo.root, repo.cell)
    return store.open(repo.root, repo.database.url, repo.cell)


def test_a_tcp_record_reads_back_as_written():
    record = _record('tool0', 7)
    back = TcpRecord.from_dict(record)
    assert back.tool == 'tool0' and back.method == 'tcp-4-point'
    assert np.allclose(back.result.T_flange_tool, T_FLANGE_TOOL, atol=1e-12)
    assert back.result.orientation_method == 'none' and back.result.approaches == 4
    assert back.inputs.labels == ['approach 1', 'approach 2', 'approach 3', 'approach 4']
    assert back.to_dict() == record


def test_a_tcp_record_stored_with_the_old_key_reads_with_the_new_one(repo):
    """Issue 39.3: T_flange_tool, a TCP record's key before T_flange_tool, still reads."""
    record = _record('tool0', 3, dz=0.01)
    result = dict(record['result'])
    result['T_flange_tcp'] = result.pop('T_flange_tool')   # legacy name: as written before
    assert repo.tcp.save_and_activate({**record, 'result': result})
    again = _reopen(repo).tcp.get(record['id'])
    assert 'T_flange_tcp' not in again['result']                # legacy name
    assert np.allclose(again['result']['T_flange_tool'], record['result']['T_flange_tool'],
                       atol=0)
    assert np.allclose(np.asarray(TcpRecord.from_dict(again).result.T_flange_tool)[2, 3],
                       T_FLANGE_TOOL[2, 3] + 0.01, atol=1e-9)


def test_the_rig_of_a_repository_ends_its_tcp_chain_at_the_active_tcp(repo):
    """Issue 30.3: every chain to the 'tcp' tool (store.rigs.rig_of: the nodes, checks and
    verbs) uses the active TCP of the cell's tool, not another tool's."""
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    from cobot_calib_ros.store.rigs import rig_of
    cell = load_cell(cell_file('sawyer_close'))
    assert rig_of(repo, cell).active.tcp_label == 'nominal'
    assert repo.tcp.save_and_activate(_record('gripper', 1, dz=0.05))
    assert rig_of(repo, cell).active.tcp is None
    assert repo.tcp.save_and_activate(_record(cell.tool_frame, 2, dz=2e-4))
    rig = rig_of(repo, cell)
    assert rig.active.tcp_label == f'tcp-{cell.tool_frame}-2'
    assert np.allclose(rig.tool('tcp')[:3, 3], T_FLANGE_TOOL[:3, 3] + [0, 0, 2e-4], atol=1e-9)
