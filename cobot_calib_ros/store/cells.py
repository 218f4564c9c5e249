"""Which cell a stored result belongs to: results are keyed by the cell they were made on.

A :class:`ResultsCell` is the cell's name and its robot's model name. A suite's name is its
namespace when it runs in one (``up --namespace plant/cell_07``: ``plant.cell_07``), else the
cell file's name (``sawyer_close``): :meth:`ResultsCell.of`, the one rule for nodes and
commands. Every record a cell stores carries ``cell`` and ``robot``; a cell's histories hold
its own records only, so two robots share a data dir (or a database) and each activates only
its own results. A record of another cell or another robot is refused by name: a
core.errors.Refusal (:func:`foreign_result`) of cause FOREIGN_RESULT.

Records stored before results were keyed by cell (no ``cell`` key in the folder store, rows
of cell ``default`` in the database) are *legacy*: a cell takes them as its own when their
robot is its robot or is not recorded (then it says so in its store's ``warnings``), never
when they were made on another robot. Their active choice and retired ids count for the cell
until it chooses for itself.
"""
from __future__ import annotations

from dataclasses import dataclass

from cobot_calib_ros.core.errors import ErrorCode, Failure, Refusal

LEGACY_CELL = 'default'     # the database rows' cell before results were keyed by cell


def foreign_result(message: str) -> Refusal:
    """The refusal of a record of another cell or another robot asked for (or given) to this
    cell: FOREIGN_RESULT."""
    return Refusal(Failure(ErrorCode.FOREIGN_RESULT, message))


@dataclass(frozen=True)
class ResultsCell:
    """The cell results are stored under: ``name`` and ``robot`` ('' : not known to the
    caller, e.g. a command given only --cell; then records are not checked by robot)."""

    name: str
    robot: str = ''

    @classmethod
    def of(cls, cell, namespace: str = '') -> ResultsCell:
        """The results cell of a suite of ``cell`` (a core.cell.Cell) running in ROS
        ``namespace`` ('' or '/': none)."""
        name = namespace.strip('/').replace('/', '.')
        return cls(name or cell.name, cell.robot)

    def __str__(self) -> str:
        return f'{self.name} ({self.robot})' if self.robot else self.name

    def problem(self, cell: str, robot: str) -> Failure | None:
        """None if a record stored under ``cell`` ('' : legacy, before keying) made on
        ``robot`` ('' : not recorded) is this cell's, else a FOREIGN_RESULT Failure saying why
        not (naming both)."""
        made = f'the {robot}' if robot else 'an unrecorded robot'
        mine = f'cell {self.name!r}' + (f' on the {self.robot}' if self.robot else '')
        if cell and cell != LEGACY_CELL and cell != self.name:
            return Failure(ErrorCode.FOREIGN_RESULT,
                           f'it was made in cell {cell!r} on {made}; this is {mine}')
        if robot and self.robot and robot != self.robot:
            return Failure(ErrorCode.FOREIGN_RESULT, f'it was made on {made}; this is {mine}')
        return None


def legacy_note(cell: ResultsCell, where: str, ids: list[str]) -> str:
    """The warning a cell's store gives when it takes legacy records as its own."""
    shown = ', '.join(ids[:5]) + (f' and {len(ids) - 5} more' if len(ids) > 5 else '')
    robot = f'the {cell.robot}' if cell.robot else 'its robot'
    return (f'{where}: {len(ids)} record(s) stored before results were keyed by cell taken '
            f'as cell {cell.name!r}\'s (made on {robot}, or no robot recorded): {shown}')
