"""`cobot-calib export ID --format kuka|abb|fanuc|ur|yaskawa`: a stored frame in the
controller's own syntax and units (core.vendor_frames), ready to paste: a user frame, or a tool
centre point (a TCP calibration id, or ``active --tool NAME``) as the controller's tool data."""
from __future__ import annotations

import json
import sys

import numpy as np

from cobot_calib_ros.cli.common import EXIT_OK, EXIT_USAGE, fail
from cobot_calib_ros.cli.db import add_db_options



def add_parser(subparsers):
    from cobot_calib_ros.core.vendor_frames import FORMATS
    p = subparsers.add_parser('export', help="a stored frame or TCP in a robot controller's "
                                             'syntax')
    p.add_argument('id', help="a user-frame or TCP calibration id, or 'active' (the cell's "
                              "active user frame; with --tool, that tool's active TCP)")
    p.add_argument('--tool', help='export the TCP of this tool (its active one for id '
                                  "'active'), as KUKA TOOL_DATA, ABB tooldata, FANUC UTOOL, "
                                  'UR set_tcp or the Yaskawa TOOL screen')
    p.add_argument('--format', required=True, choices=list(FORMATS))
    p.add_argument('--index', type=int,
                   help='base / user frame number on the controller (default 1): kuka 1-32, '
                        'fanuc 1-9, yaskawa 1-63; a tool: kuka 1-16, fanuc 1-10, yaskawa '
                        '0-63; abb and ur frames have a --name instead')
    p.add_argument('--name', help='variable name (ABB wobjdata / tooldata, UR; default '
                                     'cell_frame, a tool cobot_tcp)')
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


def find_tcp(repo, record_id: str, tool: str | None):
    """(record, T_flange_tool) of a stored TCP id (or 'active' of ``tool``), or None."""
    record = repo.tcp.active(tool or '') if record_id == 'active' else repo.tcp.get(record_id)
    if record is None or (tool and record.get('tool') != tool):
        return None
    return record, np.array(record['result']['T_flange_tool'], dtype=float)


def _stale(repo, cell_name: str | None, kind: str, record) -> tuple:
    """core.provenance.Stale of the exported ``record`` against its cell's active set (none
    when the cell is not known here: cli.db.cell_active_set)."""
    from cobot_calib_ros.cli.db import cell_active_set
    from cobot_calib_ros.store.rigs import KINDS, staleness
    cell, active = cell_active_set(repo, cell_name)
    result = KINDS[kind].typed(record)
    if active is None or result is None:
        return ()
    return staleness(repo, cell, active, kind, result)


def run(args) -> int:
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.core.vendor_frames import (check_frame_number, FORMATS,
                                                    FRAME_NUMBERS, paste_text, to_values,
                                                    TOOL_NUMBERS)
    from cobot_calib_ros.cli.db import cell_of
    from cobot_calib_ros.core.errors import Refusal
    root = paths.data_dir(args.data_dir)
    try:
        every = store.open(root, args.db)           # an id is found in any cell's results
        cell, problem = cell_of(args, every) if args.cell or args.id == 'active' else (
            None, '')
        if problem:
            return fail(f'export: {problem}', EXIT_USAGE)
        repo = store.open(root, args.db, cell) if cell else every
        found = None if args.tool else find_frame(repo, args.id)
        is_tool = found is None and (args.tool or args.id != 'active')
        if is_tool:
            found = find_tcp(repo, args.id, args.tool)
    except (ValueError, Refusal) as exc:      # Refusal: another cell's id (store.cells)
        return fail(f'export: {exc}', EXIT_USAGE)
    except OSError as exc:
        return fail(f'export: {exc}')
    if found is None:
        kind = f'TCP calibration of tool {args.tool!r} {args.id!r}' if args.tool else \
            f'user-frame calibration {args.id!r} (nor a TCP calibration)'
        return fail(f'export: no {kind} in {repo.root}; '
                    '`cobot-calib history` lists the stored ones (--data-dir, --db, --cell)')
    try:
        check_frame_number(args.format, args.index, TOOL_NUMBERS if is_tool else FRAME_NUMBERS)
    except ValueError as exc:
        return fail(f'export: --index: {exc}', EXIT_USAGE)
    record, T = found
    what = f'TCP of {record.get("tool", "")} in the flange frame' if is_tool else \
        'user frame in the robot base'
    try:
        values = to_values(T, args.format)
        name = args.name or ('cobot_tcp' if is_tool else 'cell_frame')
        text = paste_text(T, args.format, name, args.index, comment=(
            f'{what}: cobot_calib {record["id"]} ({record["method"]})'), tool=bool(is_tool))
    except ValueError as exc:
        return fail(f'export: {record["id"]}: {exc}')
    stale = _stale(repo, cell or record.get('cell'), 'tcp' if is_tool else 'user_frame', record)
    if args.json:
        fmt = FORMATS[args.format]
        print(json.dumps({'id': record['id'], 'format': args.format, 'frame': what,
                          'values': dict(zip(fmt.labels, values)),
                          'units': dict(zip(fmt.labels, fmt.units)),
                          'stale': [s.to_dict() for s in stale]}))
    else:
        print(text, end='')
    for line in stale:
        print(f'export: stale: {line.line()}', file=sys.stderr)
    return EXIT_OK
