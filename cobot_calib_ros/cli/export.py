"""`cobot-calib export ID --format kuka|abb|fanuc|ur|yaskawa`: a stored frame in the
controller's own syntax and units (core.vendor_frames), ready to paste."""
from __future__ import annotations

import json

import numpy as np

from cobot_calib_ros.cli.common import EXIT_OK, EXIT_USAGE, fail
from cobot_calib_ros.cli.db import add_db_options



def add_parser(subparsers):
    from cobot_calib_ros.core.vendor_frames import FORMATS
    p = subparsers.add_parser('export', help="a stored frame in a robot controller's syntax")
    p.add_argument('id', help="a user-frame calibration id, or 'active' (the cell's active "
                              "user frame)")
    p.add_argument('--format', required=True, choices=list(FORMATS))
    p.add_argument('--index', type=int,
                   help='base / user frame number on the controller (default 1): kuka 1-32, '
                        'fanuc 1-9, yaskawa 1-63; abb and ur frames have a --name instead')
    p.add_argument('--name', default='cell_frame', help='variable name (ABB wobjdata, UR)')
    p.add_argument('--json', action='store_true', help='the values as one JSON line')
    add_db_options(p)
    return p


def find_frame(repo, record_id: str):
    """(record, T_base_user) of a stored user frame id (or 'active'), or None."""
    history = repo.user_frames
    record = history.active() if record_id == 'active' else history.get(record_id)
    if record is None:
        return None
    return record, np.array(record['result']['T_base_user'], dtype=float)


def run(args) -> int:
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.core.vendor_frames import (FORMATS, check_frame_number, paste_text,
                                                    to_values)
    from cobot_calib_ros.cli.db import cell_of
    try:
        check_frame_number(args.format, args.index)
    except ValueError as exc:
        return fail(f'export: --index: {exc}', EXIT_USAGE)
    root = paths.data_dir(args.data_dir)
    try:
        every = store.open(root, args.db)           # an id is found in any cell's results
        cell, problem = cell_of(args, every) if args.cell or args.id == 'active' else (
            None, '')
        if problem:
            return fail(f'export: {problem}', EXIT_USAGE)
        repo = store.open(root, args.db, cell) if cell else every
        found = find_frame(repo, args.id)
    except ValueError as exc:
        return fail(f'export: {exc}', EXIT_USAGE)
    except OSError as exc:
        return fail(f'export: {exc}')
    if found is None:
        return fail(f'export: no user-frame calibration {args.id!r} in {repo.root}; '
                    '`cobot-calib history` lists the stored ones (--data-dir, --db, --cell)')
    record, T = found
    what = 'user frame in the robot base'
    try:
        values = to_values(T, args.format)
        text = paste_text(T, args.format, args.name, args.index, comment=(
            f'{what}: cobot_calib {record["id"]} ({record["method"]})'))
    except ValueError as exc:
        return fail(f'export: {record["id"]}: {exc}')
    if args.json:
        fmt = FORMATS[args.format]
        print(json.dumps({'id': record['id'], 'format': args.format, 'frame': what,
                          'values': dict(zip(fmt.labels, values)),
                          'units': dict(zip(fmt.labels, fmt.units))}))
    else:
        print(text, end='')
    return EXIT_OK
