"""`cobot-calib history`: each stored result against the previous one (store.history), per
cell, with its own uncertainty and the drift verdict; trend plots with those bands (PNG).
Every kind is listed (user frames, kinematic calibrations, TCPs, hand-eyes, intrinsics), each
with what it was measured through and whether it is active, and the cell's stale results
(core.provenance: a result measured through one that is no longer active), one line each."""
from __future__ import annotations

from datetime import datetime, timezone
import json
from pathlib import Path

from cobot_calib_ros.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, fail
from cobot_calib_ros.cli.db import add_db_options
from cobot_calib_ros.ros.time import ns_to_s, s_to_ns


def add_parser(subparsers):
    p = subparsers.add_parser('history', help="a cell's results against the previous one: "
                                              'drift, with uncertainty; trend plots')
    add_db_options(p)
    p.add_argument('--since', help='only results from this time on (ISO 8601, e.g. '
                                   '2026-11-01 or 2026-11-01T08:00; UTC unless it says)')
    p.add_argument('--json', action='store_true',
                   help='one JSON line per cell (its user frames, kinematic calibrations, '
                        'TCPs, hand-eyes, intrinsics, checks, and its stale results)')
    p.add_argument('--plots', help='folder for the trend PNGs (default <data dir>/reports)')
    p.add_argument('--no-plots', action='store_true', help='print only')
    return p


def since_ns(text: str | None) -> int:
    """ns since the epoch of an ISO 8601 time (naive: UTC); 0 for None. ValueError."""
    if not text:
        return 0
    when = datetime.fromisoformat(text)
    if when.tzinfo is None:
        when = when.replace(tzinfo=timezone.utc)
    return s_to_ns(when.timestamp())


def run(args) -> int:
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.cli.db import cell_of
    from cobot_calib_ros.store.cells import LEGACY_CELL
    from cobot_calib_ros.store.database import DatabaseError
    try:
        start = since_ns(args.since)
    except ValueError:
        return fail(f'history: --since {args.since!r} is not an ISO 8601 time; give e.g. '
                    '2026-11-01 or 2026-11-01T08:00:00', EXIT_USAGE)
    root = paths.data_dir(args.data_dir)
    try:
        every = store.open(root, args.db)
        if args.cell:
            problem = cell_of(args, every)[1]
            if problem:
                return fail(f'history: {problem}', EXIT_USAGE)
        cells = [args.cell] if args.cell else list(every.cells()) or [LEGACY_CELL]
        reports = [_cell_report(store.open(root, args.db, cell), cell, start)
                   for cell in cells]
    except DatabaseError as exc:
        return fail(f'history: {exc}')
    for report in reports:
        _print(report, args.json)
    if not args.no_plots:
        out = Path(args.plots) if args.plots else root / 'reports'
        for report in reports:
            if report['user_frames']:
                print(f'trend plot: {_plot(report, out)}', flush=True)
    worst = max((s['level'] for r in reports for s in (*r['user_frames'], *r['tcp'])
                 if s['level']), default=0)
    return EXIT_FAILED if worst >= 2 else EXIT_OK


def _cell_report(repo, cell: str, start: int) -> dict:
    import numpy as np
    from cobot_calib_ros.cli.db import cell_active_set
    from cobot_calib_ros.core.rig import KINDS
    from cobot_calib_ros.store.history import kinematic_changes, tcp_steps, user_frame_steps
    steps = []
    for step in user_frame_steps(repo.user_frames.history()):
        if step.record['stamp_ns'] < start:
            continue
        c = step.change
        steps.append({'id': step.record['id'], 'method': step.record['method'],
                      'tcp': step.record.get('tcp', ''), **_provenance(step.record, None),
                      'stamp_ns': step.record['stamp_ns'], 'previous': step.previous_id,
                      'rms_mm': step.record['result'].get('rms', 0.0) * 1e3,
                      **_change_fields(c),
                      'sigma_mrad': None if c is None else c.sigma_rotation_rad * 1e3})
    cell_model, active = cell_active_set(repo, cell)
    active_ids = set() if active is None else {active.label(k) for k in KINDS}
    kinematic = []
    records = sorted(repo.kinematics.history(), key=lambda r: (r['stamp_ns'], r['id']))
    for robot in sorted({r.get('robot', '') for r in records}):
        mine = [r for r in records if r.get('robot', '') == robot and not r.get('gate_problem')]
        for prev, new in zip([None, *mine], mine):
            if new['stamp_ns'] < start:
                continue
            changes = [] if prev is None else kinematic_changes(prev, new)
            worst = max(changes, key=lambda c: c.z, default=None)
            kinematic.append({'id': new['id'], 'robot': robot,
                              'previous': '' if prev is None else prev['id'],
                              'rms_mm': new['result'].get('rms_m', 0.0) * 1e3,
                              **_provenance(new, active_ids),
                              'largest_change': None if worst is None else {
                                  'name': worst.name, 'change': worst.change,
                                  'sigma': worst.sigma, 'z': worst.z}})
    tcp = []
    for tool, step in tcp_steps(repo.tcp.history()):
        if step.record['stamp_ns'] < start:
            continue
        c, result = step.change, step.record['result']
        tcp.append({'id': step.record['id'], 'tool': tool, 'method': step.record['method'],
                    'previous': step.previous_id,
                    'xyz_mm': [v * 1e3 for v in np.array(result['T_flange_tool'])[:3, 3]],
                    'mean_residual_mm': result.get('mean_residual_mm'),
                    'max_residual_mm': result.get('max_residual_mm'),
                    **_provenance(step.record, active_ids), **_change_fields(c)})
    hand_eye = [{'id': r['id'], 'method': r.get('method', ''),
                 'residual_mm': r['result'].get('residual_mm'),
                 'residual_mrad': r['result'].get('residual_mrad'),
                 'gate_problem': r.get('gate_problem', ''), **_provenance(r, active_ids)}
                for r in _oldest_first(repo.hand_eye.history()) if r['stamp_ns'] >= start]
    intrinsics = [{'id': r['id'], 'camera': r.get('camera', ''), 'method': r.get('method', ''),
                   'rms_px': r['result'].get('rms_px'),
                   'heldout_rms_px': r['result'].get('heldout_rms_px'),
                   'gate_problem': r.get('gate_problem', ''), **_provenance(r, active_ids)}
                  for r in _oldest_first(repo.intrinsics.history()) if r['stamp_ns'] >= start]
    for step in steps if active is not None else ():
        step['active'] = step['id'] == active.label('user_frame')
    checks = [{'id': r['id'], 'method': r['method'], 'verdict': r['result'].get('verdict'),
               'robot_s': r['result'].get('robot_seconds')}
              for r in repo.checks.history() if r['stamp_ns'] >= start] \
        if hasattr(repo, 'checks') else []
    return {'cell': cell, 'user_frames': steps, 'kinematics': kinematic, 'tcp': tcp,
            'hand_eye': hand_eye, 'intrinsics': intrinsics, 'checks': checks,
            'stale': [] if active is None else [st.to_dict() for st in active.stale],
            'stale_known': active is not None}


def _oldest_first(records) -> list:
    return sorted(records, key=lambda r: (r['stamp_ns'], r['id']))


def _provenance(record, active_ids: set[str] | None) -> dict:
    """What a result was measured through and whether it is its kind's active one (None: not
    known here, or given by the caller)."""
    from cobot_calib_ros.store.rigs import measured_through
    out = {'measured_through': measured_through(record)}
    if active_ids is not None:
        out['active'] = record['id'] in active_ids
    return out


def _change_fields(c) -> dict:
    """A frame change (core.drift; None: the first of its history) as the report shows it."""
    return {'moved_mm': None if c is None else c.translation_m * 1e3,
            'sigma_mm': None if c is None else c.sigma_translation_m * 1e3,
            'turned_mrad': None if c is None else c.rotation_rad * 1e3,
            'level': 0 if c is None else c.level,
            'verdict': 'first' if c is None else c.level_name,
            'message': '' if c is None else c.message}


def _print(report: dict, as_json: bool) -> None:
    if as_json:
        print(json.dumps(report), flush=True)
        return
    print(f'cell {report["cell"]}: {len(report["user_frames"])} user frame(s)')
    print(f'  {"id":44} {"method":14} {"rms mm":>7} {"moved mm":>16} {"turned mrad":>16}  '
          'verdict')
    for s in report['user_frames']:
        moved = '' if s['moved_mm'] is None else f'{s["moved_mm"]:.3f} +-{s["sigma_mm"]:.3f}'
        turned = '' if s['turned_mrad'] is None else \
            f'{s["turned_mrad"]:.3f} +-{s["sigma_mrad"]:.3f}'
        print(f'  {s["id"]:44} {s["method"]:14} {s["rms_mm"]:7.4f} {moved:>16} {turned:>16}  '
              f'{s["verdict"]}')
    for s in report['user_frames']:
        if s['level']:
            print(f'  {s["verdict"]}: {s["message"]}')
    for k in report['kinematics']:
        big = k['largest_change']
        text = 'the first' if big is None else (
            f'largest change {big["name"]} {big["change"]:+.3g} ({big["z"]:.1f} sigma)')
        print(f'  kinematics {k["robot"]} {k["id"]}{_active_mark(k)}: rms {k["rms_mm"]:.3f} '
              f'mm; {text}')
    for t in report['tcp']:
        x, y, z = t['xyz_mm']
        moved = '' if t['moved_mm'] is None else (
            f'; moved {t["moved_mm"]:.3f} +-{t["sigma_mm"]:.3f} mm, turned '
            f'{t["turned_mrad"]:.3f} mrad: {t["verdict"]}')
        print(f'  tcp {t["tool"]} {t["id"]}{_active_mark(t)} ({t["method"]}): {x:.3f} '
              f'{y:.3f} {z:.3f} mm, residual mean {t["mean_residual_mm"]:.3f} max {t["max_residual_mm"]:.3f} mm'
              f'{moved}')
        if t['level']:
            print(f'  {t["verdict"]}: {t["message"]}')
    for h in report['hand_eye']:
        print(f'  hand-eye {h["id"]}{_active_mark(h)}: residual {h["residual_mm"]} mm / '
              f'{h["residual_mrad"]} mrad, through kinematics '
              f'{h["measured_through"].get("kinematics", "unknown")}'
              + (f'; rejected: {h["gate_problem"]}' if h['gate_problem'] else ''))
    for i in report['intrinsics']:
        print(f'  intrinsics {i["camera"]} {i["id"]}{_active_mark(i)} ({i["method"]}): rms '
              f'{i["rms_px"]} px' + (f'; rejected: {i["gate_problem"]}' if i['gate_problem']
                                     else ''))
    for c in report['checks']:
        print(f'  check {c["id"]} ({c["method"]}): {c["verdict"]}, robot {c["robot_s"]} s')
    for stale in report['stale']:
        print(f'  stale: {stale["message"]}')


def _active_mark(entry: dict) -> str:
    return ' (active)' if entry.get('active') else ''


def _plot(report: dict, out: Path) -> Path:
    """The trend figure of ``report`` as ``out``/history-<cell>.png."""
    import matplotlib.pyplot as plt
    fig = trend_figure(report)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f'history-{report["cell"]}.png'
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


MAX_TICKS = 20      # calibrations labelled on the x axis at most (every n-th beyond)


def trend_figure(report: dict):
    """Frame change per calibration (one tick each, labelled with its date and id) with its
    k-sigma band and the WARN and ERROR tolerances."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from cobot_calib_ros.core.drift import DriftLimits
    limits = DriftLimits()
    steps = [s for s in report['user_frames'] if s['moved_mm'] is not None]
    x = list(range(1, len(steps) + 1))
    fig, axes = plt.subplots(2, 1, figsize=(max(8.0, 2.0 + 0.6 * min(len(x), MAX_TICKS)), 7),
                             sharex=True)
    for ax, key, sigma, warn, error, unit in (
            (axes[0], 'moved_mm', 'sigma_mm', limits.warn_m * 1e3, limits.error_m * 1e3, 'mm'),
            (axes[1], 'turned_mrad', 'sigma_mrad', limits.warn_rad * 1e3,
             limits.error_rad * 1e3, 'mrad')):
        values = [s[key] for s in steps]
        band = [limits.k * s[sigma] for s in steps]
        ax.fill_between(x, 0, band, alpha=0.3, label=f'{limits.k:g} standard errors')
        ax.plot(x, values, 'o-', label='change since the previous calibration')
        ax.axhline(warn, color='tab:orange', ls='--', label='WARN tolerance')
        ax.axhline(error, color='tab:red', ls='-', label='ERROR tolerance')
        for xi, s in zip(x, steps):
            if s['level']:
                ax.plot(xi, s[key], 'o', color='tab:red')
        ax.set_ylabel(f'{key.split("_")[0]} [{unit}]')
    every = -(-len(x) // MAX_TICKS) if x else 1
    shown = x[::every]
    axes[1].set_xticks(shown, [_tick_label(steps[i - 1]) for i in shown], rotation=30,
                       ha='right', fontsize=7)
    axes[0].legend(fontsize=8)
    axes[0].set_title(f'cell {report["cell"]}: user frame drift')
    axes[1].set_xlabel('calibration (UTC, id), against the one before it')
    fig.tight_layout()
    return fig


def _tick_label(step: dict) -> str:
    when = datetime.fromtimestamp(ns_to_s(step['stamp_ns']), tz=timezone.utc)
    return f'{when:%Y-%m-%d %H:%M}\n{step["id"]}'
