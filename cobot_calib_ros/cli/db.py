"""`cobot-calib db`: the results database (store.database): import a folder store, show
what is stored."""
from __future__ import annotations

from pathlib import Path

from cobot_calib_ros.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, fail


DATA_DIR_HELP = 'results root (default $COBOT_CALIB_DATA, else ~/.ros/cobot_calib)'


def add_db_options(p) -> None:
    """--data-dir, --db, --cell: which repository (shared by db, history, check)."""
    p.add_argument('--data-dir', help=DATA_DIR_HELP)
    p.add_argument('--db', help='database URL, e.g. postgresql://user@host/db (default '
                                '$COBOT_CALIB_DB, else the SQLite file in the data dir)')
    p.add_argument('--cell', help="the results' cell: its name (a suite's namespace, e.g. "
                                  'cell_07, else its cell file\'s name, e.g. sawyer_close)')


def add_parser(subparsers):
    p = subparsers.add_parser('db', help='the results database: import a folder store, info')
    sub = p.add_subparsers(dest='db_command', required=True, metavar='SUBCOMMAND')
    imp = sub.add_parser('import', help='bring a folder store (calibrations/, trials/, ...) '
                                        'into the database, nothing lost')
    imp.add_argument('source', help='the folder store, e.g. an older ~/.ros/cobot_calib')
    add_db_options(imp)
    info = sub.add_parser('info', help='the database URL and how many results of each kind')
    add_db_options(info)
    return p


def known_cells_text(cells: dict[str, list[str]]) -> str:
    """'a (sawyer), b (iiwa7)' of repository.cells(); 'none' when there is none."""
    from cobot_calib_ros.store.cells import LEGACY_CELL

    def one(name: str, robots: list[str]) -> str:
        if name == LEGACY_CELL:
            return f'{name} (stored before results were keyed by cell)'
        robots = [r for r in robots if r]
        return f'{name} ({", ".join(robots)})' if robots else name
    return ', '.join(one(n, r) for n, r in cells.items()) or 'none'


def cell_of(args, repo) -> tuple[str | None, str]:
    """(the results cell --cell names, or the only one that has results, None: the store as
    before cells; '') or (None, why not: an unknown --cell, or several cells and none given).
    ``repo``: the data dir's repository opened with no cell. (Cell 'default': the results
    stored before keying by cell, store.cells.)"""
    from cobot_calib_ros.store.cells import LEGACY_CELL
    cells = repo.cells()
    if args.cell:
        if args.cell in cells:
            return args.cell, ''
        return None, (f'no results of cell {args.cell!r} in {repo.root}; the cells with '
                      f'results: {known_cells_text(cells)}')
    keyed = [c for c in cells if c != LEGACY_CELL]
    if len(keyed) > 1:
        return None, (f'the results of several cells are stored: {known_cells_text(cells)}; '
                      'give --cell')
    return (keyed[0] if keyed else None), ''


def open_database_repository(args):
    """The database repository of --data-dir/--db/--cell, or an error message."""
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.store.database import sqlite_url
    from cobot_calib_ros.store.repository import DatabaseRepository
    root = paths.data_dir(args.data_dir)
    repo = store.open(root, args.db, args.cell)
    if not isinstance(repo, DatabaseRepository):   # a folder store: its own database
        repo = store.open(root, sqlite_url(root), args.cell)
    return repo


def run(args) -> int:
    from cobot_calib_ros.store.database import DatabaseError
    try:
        repo = open_database_repository(args)
        if args.db_command == 'import':
            return _import(args, repo)
        return _info(repo)
    except DatabaseError as exc:
        return fail(f'db: {exc}; check --db / $COBOT_CALIB_DB (is the server up?)')


def _info(repo) -> int:
    from cobot_calib_ros.store.database import KINDS
    for cell in repo.database.cells():
        counts = {kind: len(repo.database.rows(cell, kind)) for kind in KINDS}
        print(f'{cell}: ' + ', '.join(f'{n} {kind}' for kind, n in counts.items() if n))
    print(f'database: {repo.database}')
    return EXIT_OK


def _import(args, repo) -> int:
    from cobot_calib_ros.store.importer import import_folder
    source = Path(args.source)
    if not source.is_dir():
        return fail(f'db import: {source} is not a folder; give a data dir written by the '
                    'folder store (with calibrations/, hand_eye/, kinematics/, trials/)',
                    EXIT_USAGE)
    report = import_folder(source, repo)
    for line in report.skipped:
        print(f'skipped: {line}')
    where = f'cell {repo.cell_name}' if repo.cell else 'the cells the records name'
    print(f'{report.summary()} into {repo.database} ({where})')
    return EXIT_FAILED if report.skipped else EXIT_OK


def cell_active_set(repo, cell_name: str | None):
    """(core Cell, store.rigs.active_set) of results cell ``cell_name`` when it is named
    after a cell file (a suite without a namespace), else (None, None): then which results
    are stale is not known here."""
    from cobot_calib_ros import paths
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.store.rigs import active_set
    if not cell_name:
        return None, None
    try:
        cell = load_cell(paths.cell_file(cell_name))
        return cell, active_set(repo, cell)
    except (CellFileError, OSError, ValueError, KeyError):
        return None, None
