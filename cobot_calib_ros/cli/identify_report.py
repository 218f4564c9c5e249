"""The one printer of `cobot-calib identify` reports (api.identification: identify_source and
identify_on_suite give the same shape); each section is printed when the report has it."""
from __future__ import annotations

import json

from cobot_calib_ros.api.identification import PAPER_RATIO_PERCENT
from cobot_calib_ros.core.kinematics.identification.gates import Verdict

MAX_CORRELATED_LINES = 10
# parameter names that are angles (a prismatic joint's offset_ is a length: printed as mrad)
ANGLES = ('alpha', 'theta', 'roll', 'pitch', 'yaw', 'offset_', 'compliance_')


def print_report(report: dict, as_json: bool = False) -> None:
    print(json.dumps(report, indent=2) if as_json else text(report))


def verdict_line(report: dict) -> str:
    """'passed' or 'REFUSED: <problem>; <problem>' of a report's verdict."""
    return Verdict(tuple(report['verdict']['problems'])).line()


def text(report: dict) -> str:
    lines = [_headline(report)]
    held = report.get('held_out')
    if held:
        v = report['validation']
        how = f'leave one {v["leave_out"]} out' if 'leave_out' in v else f'{v["folds"]}-fold'
        lines.append(f'held out ({how}) {"rmse":>8} {"mean":>8} {"max":>8} {"rot rms":>9}')
        for name in ('nominal', 'calibrated'):
            s = held[name]
            rot = '' if s['rot_rms_mrad'] is None else f'{s["rot_rms_mrad"]:>6.2f} mrad'
            lines.append(f'{name:<{len(how) + 11}} {s["rmse_mm"]:>5.3f} mm '
                         f'{s["mean_mm"]:>5.3f} mm {s["max_mm"]:>5.3f} mm {rot}')
    lines.append(_gate(report))
    spheres = report.get('collections', {}).get('spheres', {})
    if 'robot_s' in spheres:
        lines.append(f'robot time of the sphere collection: {spheres["robot_s"]:.1f} s '
                     f'({spheres["robot_s_at_paper_hold"]:.1f} s at the paper\'s 1 s hold)')
    if 'stop_reason' in spheres:
        lines.append(f'planned collection stopped on {spheres["stop_reason"]}')
    if report.get('partial'):
        lines.append(report['partial'])
    lines += [f'dropped {d["name"]}: {d["reason"]}' for d in report['dropped']]
    lines += [f'held {h["name"]} at nominal: {h["reason"]}' for h in report.get('held', ())]
    lines += [f'large: {note}' for note in report.get('large', ())]
    prior = report.get('prior')
    if prior:
        lines.append(f'prior around nominal: {prior["length_mm"]:g} mm, {prior["angle_mrad"]:g} '
                     f'mrad (data sigma {prior["data_sigma_mm"]:.3g} mm)')
    lines += _correlated(report) + [f'outlier: sample {o["sample"]} ({o["error_mm"]:.3f} mm)'
                                    for o in report.get('outliers', ())]
    lines.append(parameters_table(report['identified']))
    for region, rows in report.get('tracker', {}).items():
        title = {'volume': 'calibrated volume', 'workspace': 'workspace spread'}.get(region,
                                                                                      region)
        lines += [f'\nabsolute error, laser tracker, {title} ({rows["nominal"]["count"]} '
                  'configurations) [mm]   (the paper\'s Table 5)',
                  f'{"":<12}{"mean":>9}{"std":>9}{"min":>9}{"max":>9}']
        lines += [f'{name:<12}{rows[name]["mean_mm"]:9.3f}{rows[name]["std_mm"]:9.3f}'
                  f'{rows[name]["min_mm"]:9.3f}{rows[name]["max_mm"]:9.3f}'
                  for name in ('calibrated', 'nominal')]
        lines.append(f'max calibrated / nominal: {rows["ratio_max_percent"]:.1f} % (paper, on '
                     f'its spread: {PAPER_RATIO_PERCENT} %)')
    if report.get('table6'):
        lines.append(f'\n{report["table6"]}')
    if report.get('unseen'):
        from cobot_calib_ros.store.kinematics import unseen_note
        lines.append(unseen_note(report['unseen']))
    if report.get('calibration_id'):
        paths = [report[k] for k in ('record_path', 'yaml_path', 'urdf_path',
                                     'ur_kinematics_path') if report.get(k)]
        active = 'stored and active' if report.get('active', True) else 'stored, NOT active'
        lines.append(f'\n{active}: {report["calibration_id"]}' + ''.join(
            f'\n  {path}' for path in paths))
    elif report.get('not_stored'):
        lines.append(f'\nnothing stored: {report["not_stored"]}')
    return '\n'.join(lines)


def _headline(report: dict) -> str:
    converged = f'converged: {"yes" if report["converged"] else "NO"}'
    if 'parameters_kept' not in report:            # a CalibrationJob's (bag, collection, suite)
        return f'\n{report["message"]}; {converged}'
    return (f'{report["robot"]}, {report["measurement"]} ({report["samples"]} samples), '
            f'model {report["model"]}: {report["parameters_kept"]} parameters kept (textbook '
            f'minimum {report["parameters_minimum"]}), condition number '
            f'{report["condition_number"]:.1f}, {converged}')


def _gate(report: dict) -> str:
    if not report['verdict']['passed']:
        return f'gate: {verdict_line(report)}'
    bounds = report.get('bounds')
    offsets = report.get('offset_bound_mrad')
    within = f'deviations within {bounds["length_mm"]:g} mm / {bounds["angle_mrad"]:g} mrad' \
        + (f' / zero offsets {offsets:g} mrad' if offsets else '') \
        if bounds else 'every deviation within its bound'
    compared = ', held out no worse than nominal' if report.get('held_out') else \
        ', validation no worse than nominal' if report.get('tracker') else ''
    return f'gate: passed (converged, {within}{compared})'


def _correlated(report: dict) -> list[str]:
    parameters = {p['name'] for p in report['identified']}
    correlated = report.get('correlated', ())
    pairs = [c for c in correlated if c['a'] in parameters or c['b'] in parameters]
    lines = [f'correlated {c["a"]} ~ {c["b"]}: {c["correlation"]:+.3f}'
             for c in pairs[:MAX_CORRELATED_LINES]]
    hidden = len(correlated) - min(len(pairs), MAX_CORRELATED_LINES)
    if hidden:
        lines.append(f'{hidden} more correlated pairs (of the frames and targets, or past the '
                     f'first {MAX_CORRELATED_LINES}): --json lists them')
    return lines


def parameters_table(identified: list[dict]) -> str:
    """Each parameter as its deviation from nominal (as the paper's tables) and absolute, in
    mm (lengths) or mrad (angles); the ± is one standard deviation of the identified value
    (blank where the report has none)."""
    width = max([14] + [len(p['name']) + 1 for p in identified])    # URDF joint names are long
    lines = [f'\n{"parameter":<{width}}{"deviation":>16}{"std":>12}{"nominal":>16}'
             f'{"identified":>16}']
    for p in identified:
        length = not p['name'].startswith(ANGLES)
        unit = 'mm' if length else 'mrad'
        value, nominal = p['value'] * 1e3, p['nominal'] * 1e3
        std = f'{p["std"] * 1e3:>7.4f} {unit:<4}' if 'std' in p else ' ' * 12
        lines.append(f'{p["name"]:<{width}}{value - nominal:>+11.4f} {unit:<4}{std}'
                     f'{nominal:>11.4f} {unit:<4}{value:>11.4f} {unit}')
    return '\n'.join(lines)
