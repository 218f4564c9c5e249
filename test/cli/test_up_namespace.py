"""`up --namespace`: which namespaces are refused before anything starts, and the nodes'
environment (the database; the cell their results go under each node knows from its cell
file and namespace). No nodes are started here."""
from __future__ import annotations

import pytest

from cobot_calib_ros.cli import up
from cobot_calib_ros.cli.main import main


@pytest.mark.parametrize('namespace, ok', [
    ('cell_07', True), ('plant/cell_07', True), ('', True), ('7cell', False),
    ('cell 07', False), ('cell-07', False), ('cell//07', False)])
def test_namespace_problem(namespace, ok):
    assert (up.namespace_problem(namespace) is None) == ok


def test_a_bad_namespace_starts_nothing(capsys):
    assert main(['up', '--namespace', 'cell-07']) == 2
    err = capsys.readouterr().err
    assert "--namespace 'cell-07': a namespace is letters" in err and 'nothing started' in err


def test_the_nodes_get_the_given_database_and_no_cell_by_environment(monkeypatch):
    monkeypatch.delenv('COBOT_CALIB_DB', raising=False)
    monkeypatch.delenv('COBOT_CALIB_ROBOT', raising=False)
    monkeypatch.delenv('COBOT_CALIB_CELL', raising=False)
    assert up.suite_environment('') is None                 # the nodes inherit this process's
    env = up.suite_environment('postgresql://u@h/plant', 'iiwa7')
    assert env['COBOT_CALIB_DB'] == 'postgresql://u@h/plant'
    assert env['COBOT_CALIB_ROBOT'] == 'iiwa7'              # the results' provenance
    assert 'COBOT_CALIB_CELL' not in env                   # each node knows its cell itself
    assert env['PATH']                                      # the rest of the environment kept


def test_a_node_s_results_cell_is_its_namespace_else_its_cell_file_s_name():
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.paths import cell_file
    from cobot_calib_ros.store.cells import ResultsCell
    iiwa = load_cell(cell_file('iiwa7_close'))
    assert ResultsCell.of(iiwa, '/') == ResultsCell('iiwa7_close', 'iiwa7')
    assert ResultsCell.of(iiwa, '/plant/cell_07') == ResultsCell('plant.cell_07', 'iiwa7')


def test_the_robot_model_of_the_cell_given_to_up():
    assert (up._robot_of('iiwa7_close'), up._robot_of('sawyer_close')) == ('iiwa7', 'sawyer')
    assert up._robot_of('/no/such/cell.yaml') == ''
