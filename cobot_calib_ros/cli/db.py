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
    p.add_argument('--cell', help='cell name of the results (default $COBOT_CALIB_CELL or '
                                  "'default')")


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


def open_database_repository(args):
    """The database repository of --data-dir/--db/--cell, or an error message."""
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.store.database import sqlite_url
    from cobot_calib_ros.store.repository import DatabaseRepository
    root = paths.data_dir(args.data_dir)
    repo = store.open(root, args.db, args.cell)
    if not isinstance(repo, DatabaseRepository):   # a folder store: its own database
        repo = DatabaseRepository(root, sqlite_url(root), args.cell or repo_cell())
    return repo


def repo_cell() -> str:
    import os
    from cobot_calib_ros.store.database import CELL_ENV, DEFAULT_CELL
    return os.environ.get(CELL_ENV) or DEFAULT_CELL


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
    for cell in repo.database.cells():
        counts = {kind: len(repo.database.rows(cell, kind)) for kind in (
            'user_frame', 'hand_eye', 'kinematics', 'check', 'trial', 'collection')}
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
    print(f'{report.summary()} into {repo.database} (cell {repo.cell})')
    return EXIT_FAILED if report.skipped else EXIT_OK
