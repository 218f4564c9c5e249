"""Human reports of ISO 9283 repeatability trials: a table and a box plot, in millimetres.

The table follows the seed paper's Tables 1-5 (one row per experiment with RP_i per point and
RP_all), followed by one block per trial with the per-point mean d_i, mean D_i, sigma_i and
RP_i of eqs (9)-(14). The box plot follows Figures 2-4: the probe distances d_i,n of each
point, one box per trial side by side (reference vs the calibration methods), solid line the
median, dashed line the mean; one panel per probed axis, each box with its band mean d_i +-
RP_i and the value of RP_i written above it, and the probe's mid-range (where the set-up put
every point) dotted across, as ISO 9283 reports show repeatability per axis.

All numbers come from :mod:`cobot_calib_ros.core.repeatability`; this module only converts
metres to millimetres and lays them out. Only complete cycles are used, in the table and in
the plot alike, so both describe the same samples.

matplotlib is imported inside :func:`box_plot`, so importing this module stays cheap.
"""
from __future__ import annotations

from collections.abc import Sequence
import io
import math
from pathlib import Path
from typing import Any

import numpy as np

from cobot_calib_ros.core.repeatability import (complete_cycles, iso9283_rp_from_axes,
                                                 overall_rp, point_statistics)
from cobot_calib_ros.core.repeatability.trial import mean_calibration_seconds
from cobot_calib_ros.store.files import atomic_write_bytes, atomic_write_text, check_id
from cobot_calib_ros.store.trials import TrialData, TrialStore

MM_PER_M = 1000.0
DECIMALS = 3  # 1 um: the paper prints 0.01 mm, too coarse for a good reference repeatability
MISSING = 'n/a'
REFERENCE_METHOD = 'reference'
REFERENCE_COLOR = '0.6'  # grey, so the methods stand out against the robot's own repeatability
MAX_STEM_CHARS = 100
PNG_SIZE_IN = (10.0, 5.0)
PNG_DPI = 120
# RP_all [mm] the first paper measured on the Sawyer: Tables 1-3 (the built-in one-landmark
# method, RPS, and the reference, per axis) and Tables 4-5 (z, close and wide set-ups).
PAPER_RP_ALL_MM = {
    ('landmark_single', 'x', None): (0.70, 'Table 1'),
    ('landmark_single', 'y', None): (0.39, 'Table 2'),
    ('landmark_single', 'z', None): (1.42, 'Table 3'),
    ('reference', 'x', None): (0.08, 'Table 1'),
    ('reference', 'y', None): (0.16, 'Table 2'),
    ('reference', 'z', 'close'): (0.08, 'Table 4'),
    ('three_point', 'z', 'close'): (0.33, 'Table 4'),
    ('five_point_lsq', 'z', 'close'): (0.12, 'Table 4'),
    ('reference', 'z', 'wide'): (0.24, 'Table 5'),
    ('three_point', 'z', 'wide'): (0.53, 'Table 5'),
    ('five_point_lsq', 'z', 'wide'): (0.36, 'Table 5'),
}


def paper_rp_all_mm(method: str, axis: str, layout: str) -> tuple[float, str] | None:
    """(RP_all [mm], table) the paper gives for this method, axis and set-up, else None."""
    return PAPER_RP_ALL_MM.get((method, axis, layout)) or PAPER_RP_ALL_MM.get(
        (method, axis, None))


def trial_summary(trial: TrialData) -> dict[str, Any]:
    """Per-point repeatability of one trial in mm, NaN-free (None where not computable)."""
    meta = trial.meta
    stats = point_statistics(trial.distances)
    points = []
    for i, name in enumerate(meta['point_names']):
        values = (stats.mean_distance[i], stats.mean_deviation[i], stats.sigma[i], stats.rp[i])
        mm = [_to_mm(v) if stats else None for v in values]
        points.append(dict(zip(('name', 'mean_d_mm', 'mean_D_mm', 'sigma_mm', 'rp_mm'),
                               [name, *mm])))
    rp_all_mm, note = _rp_all_mm(points, stats.cycles)
    seconds = mean_calibration_seconds(meta)
    paper = paper_rp_all_mm(meta['method'], meta['axis'], meta['layout'])
    return {'id': meta['id'], 'method': meta['method'], 'axis': meta['axis'],
            'layout': meta['layout'], 'status': meta['status'], 'cycles': stats.cycles,
            'cycles_total': meta['cycles_total'], 'points': points,
            'rp_all_mm': rp_all_mm, 'note': note,
            'calibration_s': seconds if math.isfinite(seconds) else None,
            'paper_rp_all_mm': None if paper is None else paper[0],
            'paper_table': None if paper is None else paper[1]}


def format_table(summaries: Sequence[dict[str, Any]]) -> str:
    """Plain-text tables of :func:`trial_summary` results: the paper's RP table, then details."""
    if not summaries:
        raise ValueError('no trial summaries to format')
    blocks = [_rp_table(summaries)] + [_detail_block(s) for s in summaries]
    return '\n\n'.join(blocks) + '\n'


def rp_3d(trials: Sequence[TrialData]) -> dict[str, dict[str, Any]]:
    """ISO 9283 RP_l [mm] per point for each method that has an x, a y and a z trial.

    The single-axis probe measures one axis per trial (paper section 4.2); cycle j of the
    three trials is taken as one attained position (``iso9283_rp_from_axes``). Only cycles
    complete in all three are used. Keyed by method; the newest trial per axis wins.
    """
    by_method: dict[str, dict[str, TrialData]] = {}
    for trial in trials:
        by_method.setdefault(trial.meta['method'], {})[trial.meta['axis']] = trial
    out = {}
    for method, axes in by_method.items():
        if set(axes) != {'x', 'y', 'z'} or len({tuple(t.meta['point_names'])
                                                  for t in axes.values()}) != 1:
            continue
        runs = [axes[a].distances[:, complete_cycles(axes[a].distances)] for a in 'xyz']
        n = min(r.shape[1] for r in runs)
        if n < 2:
            continue
        names = axes['z'].meta['point_names']
        rp = [iso9283_rp_from_axes(*(r[i, :n] for r in runs)) * MM_PER_M
              for i in range(len(names))]
        out[method] = {'points': names, 'rp_mm': rp, 'cycles': n,
                       'trials': [axes[a].meta['id'] for a in 'xyz']}
    return out


def format_rp_3d(results: dict[str, dict[str, Any]]) -> str:
    """The three-dimensional RP_l table of :func:`rp_3d`."""
    names = next(iter(results.values()))['points']
    rows = [['Experiment', *(f'RP_l {n} [mm]' for n in names), 'cycles']]
    for method, r in results.items():
        rows.append([method, *(_fmt(v) for v in r['rp_mm']), str(r['cycles'])])
    return ('ISO 9283 three-dimensional repeatability RP_l from the x, y and z trials\n\n'
            + _grid(rows) + '\n')


def box_plot(trials: Sequence[TrialData], path: Path, title: str | None = None) -> Path:
    """Write a PNG box plot of the probe distances [mm] per point and trial; returns path."""
    if not trials:
        raise ValueError('no trials to plot')
    figure = _box_figure(trials, title)
    buffer = io.BytesIO()
    figure.savefig(buffer, format='png', dpi=PNG_DPI)
    path = Path(path)
    atomic_write_bytes(path, buffer.getvalue())
    return path


def write_report(store: TrialStore, trial_ids: Sequence[str],
                 out_dir: Path) -> tuple[Path, Path, str]:
    """Box plot PNG and Markdown table of the given trials in ``out_dir``.

    Returns (png path, table path, table text). Raises ValueError naming every trial id that
    is malformed, unknown or unreadable, with the trials that can be reported instead.
    """
    trials = _load_trials(store, trial_ids)
    table = format_table([trial_summary(t) for t in trials])
    three_d = rp_3d(trials)
    if three_d:
        table += '\n' + format_rp_3d(three_d)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = _report_stem([t.meta['id'] for t in trials])
    png_path = box_plot(trials, out_dir / f'{stem}.png')
    table_path = out_dir / f'{stem}.md'
    atomic_write_text(table_path, _markdown(table, png_path.name, _data_warnings(store, trials)))
    return png_path, table_path, table


def _to_mm(value_m: float) -> float | None:
    value = float(value_m)
    return value * MM_PER_M if math.isfinite(value) else None


def _rp_all_mm(points: list[dict[str, Any]], cycles: int) -> tuple[float | None, str | None]:
    """RP_all over the points that have an RP_i, and a note when some or all have none."""
    rps = [p['rp_mm'] for p in points if p['rp_mm'] is not None]
    skipped = [p['name'] for p in points if p['rp_mm'] is None]
    if not rps:
        return None, f'no RP: {cycles} complete cycle(s), at least 2 are needed'
    if skipped:
        note = f'RP_all over {len(rps)} of {len(points)} points; no RP_i for {", ".join(skipped)}'
        return overall_rp(rps), note
    return overall_rp(rps), None


def _fmt(value_mm: float | None) -> str:
    return MISSING if value_mm is None else f'{value_mm:.{DECIMALS}f}'


def _grid(rows: list[list[str]], indent: str = '') -> str:
    """Columns padded to equal width: the first left-aligned, the others right-aligned."""
    widths = [max(len(row[c]) for row in rows) for c in range(len(rows[0]))]
    lines = []
    for row in rows:
        cells = [row[0].ljust(widths[0])] + [v.rjust(w) for v, w in zip(row[1:], widths[1:])]
        lines.append(indent + '  '.join(cells).rstrip())
    return '\n'.join(lines)


def _point_names(summaries: Sequence[dict[str, Any]]) -> list[str]:
    """Point names of all summaries in order of first appearance."""
    names: dict[str, None] = {}
    for summary in summaries:
        names.update((p['name'], None) for p in summary['points'])
    return list(names)


def _rp_table(summaries: Sequence[dict[str, Any]]) -> str:
    """The paper's Tables 1-5: one row per experiment, RP_i per point, then RP_all."""
    names = _point_names(summaries)
    rows = [['Experiment', *(f'RP_{n} [mm]' for n in names), 'RP_all [mm]',
             'paper RP_all [mm]', 'calibration [s]']]
    for summary in summaries:
        rp_by_name = {p['name']: _fmt(p['rp_mm']) for p in summary['points']}
        paper = (MISSING if summary['paper_rp_all_mm'] is None else
                 f'{summary["paper_rp_all_mm"]:.2f} ({summary["paper_table"]})')
        seconds = (MISSING if summary['calibration_s'] is None
                   else f'{summary["calibration_s"]:.1f}')
        rows.append([f'{summary["method"]} ({summary["id"]})',
                     *(rp_by_name.get(n, '-') for n in names), _fmt(summary['rp_all_mm']),
                     paper, seconds])
    return ('Positioning repeatability RP (ISO 9283, eqs 9-14), values in mm; paper: the '
            'first paper\'s Tables 1-5 for the same method, axis and set-up; calibration: '
            'robot time of one cycle\'s calibration pass (moves, holds; simulated on the mock)'
            '\n\n' + _grid(rows))


def _detail_block(summary: dict[str, Any]) -> str:
    header = (f'Trial {summary["id"]}: method {summary["method"]}, {summary["axis"]}-axis, '
              f'layout {summary["layout"]}, {summary["cycles"]} of {summary["cycles_total"]} '
              f'cycles complete (status {summary["status"]})')
    rows = [['Point', 'mean d_i [mm]', 'mean D_i [mm]', 'sigma_i [mm]', 'RP_i [mm]']]
    for p in summary['points']:
        rows.append([p['name'], *(_fmt(p[k]) for k in
                                  ('mean_d_mm', 'mean_D_mm', 'sigma_mm', 'rp_mm'))])
    lines = [header, _grid(rows, indent='  '), f'  RP_all = {_fmt(summary["rp_all_mm"])} mm']
    if summary['note']:
        lines.append(f'  note: {summary["note"]}')
    return '\n'.join(lines)


def _plotted_distances_mm(trial: TrialData) -> dict[str, np.ndarray]:
    """Per point name, the distances [mm] of the complete cycles (the samples of the table)."""
    used = trial.distances[:, complete_cycles(trial.distances)] * MM_PER_M
    return dict(zip(trial.meta['point_names'], used))


def _trial_label(summary: dict[str, Any]) -> str:
    return (f'{summary["method"]} ({summary["id"]}, n = {summary["cycles"]} cycles, '
            f'RP_all {_fmt(summary["rp_all_mm"])} mm)')


def _default_title(trials: Sequence[TrialData]) -> str:
    layouts = ', '.join(dict.fromkeys(str(t.meta['layout']) for t in trials))
    return f'Probe distances per point, layout {layouts}'


def probe_mid_range_mm(trials: Sequence[TrialData]) -> float | None:
    """The probe's mid-range [mm] the trials set their points to (F_i, README), from the
    range stored with them (``probe_range_m``); None when none stored it or they differ."""
    mids = {round(0.5 * (lo + hi) * MM_PER_M, 9) for lo, hi in
            (t.meta['probe_range_m'] for t in trials if t.meta.get('probe_range_m'))}
    return mids.pop() if len(mids) == 1 else None


def _box_figure(trials: Sequence[TrialData], title: str | None):
    """A matplotlib Figure (Agg canvas, no pyplot state) of the probe distances per point:
    one panel per probed axis, as ISO 9283 reports give each axis apart. Per point and trial a
    box of d_i,n (median solid, mean dashed), the band mean d_i +- RP_i beside it with RP_i
    written above, the probe's mid-range dotted; the legend below the panels."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    axes_present = [a for a in ('x', 'y', 'z') if any(t.meta['axis'] == a for t in trials)]
    figure = Figure(figsize=(max(PNG_SIZE_IN[0], 5.0 * len(axes_present)), PNG_SIZE_IN[1]),
                    layout='constrained')
    FigureCanvasAgg(figure)
    panels = figure.subplots(1, len(axes_present), squeeze=False)[0]
    colors = dict(zip((id(t) for t in trials), _trial_colors(trials)))
    mid_range = probe_mid_range_mm(trials)
    handles = []
    for ax, axis in zip(panels, axes_present):
        shown = [t for t in trials if t.meta['axis'] == axis]
        handles += _axis_panel(ax, axis, shown, colors, mid_range, Patch)
    handles += [Line2D([], [], color='black', linestyle='-', label='median'),
                Line2D([], [], color='black', linestyle='--', label='mean'),
                Line2D([], [], color='black', marker='_', markersize=10, linestyle='-',
                       label=r'band $\bar d_i \pm RP_i$, RP_i [mm] written above')]
    if mid_range is not None:
        handles.append(Line2D([], [], color='0.3', linestyle=':',
                              label=f'probe mid-range {mid_range:.3f} mm'))
    figure.suptitle(title or _default_title(trials))
    figure.legend(handles=handles, loc='outside lower center', fontsize='small',
                  ncols=2)
    return figure


def _axis_panel(ax, axis: str, trials: Sequence[TrialData], colors: dict[int, str],
                mid_range: float | None, Patch) -> list:
    """One axis's boxes, RP bands and labels in ``ax``; the legend handles of its trials."""
    per_trial = [_plotted_distances_mm(t) for t in trials]
    names = list(dict.fromkeys(n for d in per_trial for n in d))
    width = 0.8 / len(trials)
    handles, label_at = [], []
    for t, (trial, distances) in enumerate(zip(trials, per_trial)):
        summary = trial_summary(trial)
        rp = {p['name']: (p['mean_d_mm'], p['rp_mm']) for p in summary['points']}
        groups = [g for g, name in enumerate(names) if name in distances]
        offset = (t - (len(trials) - 1) / 2) * width
        ax.boxplot([distances[names[g]] for g in groups],
                   positions=[g + offset for g in groups], widths=0.55 * width,
                   patch_artist=True, showmeans=True, meanline=True,
                   boxprops={'facecolor': colors[id(trial)], 'alpha': 0.8},
                   medianprops={'color': 'black', 'linestyle': '-'},
                   meanprops={'color': 'black', 'linestyle': '--'},
                   flierprops={'markersize': 3})
        for g in groups:
            mean, rp_i = rp[names[g]]
            if rp_i is None:
                continue
            x = g + offset + 0.35 * width
            ax.errorbar(x, mean, yerr=rp_i, color=colors[id(trial)], capsize=3,
                        elinewidth=1.2, marker='_', markersize=6, markeredgecolor='black')
            top = max(mean + rp_i, float(np.max(distances[names[g]])))  # above any flier
            label_at.append((g + offset, top, _fmt(rp_i)))
        handles.append(Patch(facecolor=colors[id(trial)], alpha=0.8,
                             label=f'{axis}: {_trial_label(summary)}'))
    if mid_range is not None:
        ax.axhline(mid_range, color='0.3', linestyle=':', linewidth=1.0, zorder=0)
    low, high = ax.get_ylim()
    tops = [y for _, y, _ in label_at]
    high = max([high, *tops])
    span = high - low
    for x, y, text in label_at:      # RP_i above its band, inside the panel
        ax.annotate(text, (x, y), xytext=(0, 4), textcoords='offset points', ha='center',
                    va='bottom', rotation=90, fontsize='x-small')
    ax.set_ylim(low, high + 0.22 * span)
    ax.set_xticks(range(len(names)), names)
    ax.set_xlim(-0.5, len(names) - 0.5)
    ax.set_xlabel('point')
    ax.set_ylabel(r'probe distance $d_{i,n}$ [mm]')
    ax.set_title(f'{axis}-axis')
    ax.grid(axis='y', alpha=0.3)
    return handles


def _trial_colors(trials: Sequence[TrialData]) -> list[str]:
    palette = iter(f'C{i}' for i in range(len(trials)))
    return [REFERENCE_COLOR if t.meta['method'] == REFERENCE_METHOD else next(palette)
            for t in trials]


def _load_trials(store: TrialStore, trial_ids: Sequence[str]) -> list[TrialData]:
    if not trial_ids:
        raise ValueError('no trial ids given; name at least one trial to report')
    trials, problems = [], []
    for trial_id in dict.fromkeys(trial_ids):
        try:
            trial = store.load(check_id(trial_id))
        except ValueError:
            problems.append(f'{trial_id!r}: not a valid trial id')
            continue
        if trial is None:
            problems.append(f'{trial_id!r}: {_load_failure(store, trial_id)}')
        else:
            trials.append(trial)
    if problems:
        known = [m['id'] for m in store.list_trials()]
        hint = (f'trials in {store.directory}: {", ".join(known)}' if known
                else f'there are no readable trials in {store.directory}')
        raise ValueError(f'cannot report {"; ".join(problems)}. Pick existing trial ids ({hint}).')
    return trials


def _load_failure(store: TrialStore, trial_id: str) -> str:
    """Why ``store.load(trial_id)`` returned None, from the store's warnings."""
    trial_dir = store.directory / trial_id
    if not trial_dir.is_dir():
        return 'unknown trial (no such directory)'
    reasons = [w for w in store.warnings
               if w.startswith((f'{trial_dir}:', f'{trial_dir}/trial.yaml:'))]
    return f'unreadable ({reasons[-1]})' if reasons else 'unreadable'


def _data_warnings(store: TrialStore, trials: Sequence[TrialData]) -> list[str]:
    """Store warnings about the reported trials' files, e.g. ignored measurement lines."""
    dirs = tuple(f'{store.directory / t.meta["id"]}/' for t in trials)
    return [w for w in store.warnings if w.startswith(dirs)]


def _report_stem(trial_ids: Sequence[str]) -> str:
    stem = 'repeatability_' + '+'.join(trial_ids)
    if len(stem) > MAX_STEM_CHARS:
        stem = f'repeatability_{trial_ids[0]}+{len(trial_ids) - 1}_more'
    return stem


def _markdown(table: str, png_name: str, warnings: Sequence[str]) -> str:
    lines = ['# Positioning repeatability (ISO 9283)', '', f'![probe distances]({png_name})',
             '', '```text', table.rstrip('\n'), '```', '']
    if warnings:
        lines += ['Data warnings from the trial files:', '',
                  *(f'- {w}' for w in warnings), '']
    return '\n'.join(lines)
