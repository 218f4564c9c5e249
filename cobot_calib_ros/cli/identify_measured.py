"""`cobot-calib identify --measurement KIND --source FILE`: any arm from its URDF (or a DH table),
identified offline from a measurement file (CSV + YAML sidecar, or a MUKCa folder), validated
on held-out rows (k-fold by default, or one group at a time). Parses and prints; the work is
api.identification.identify_file."""
from __future__ import annotations

import json
import math

from cobot_calib_ros.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, fail
from cobot_calib_ros.api.identification import DEFAULT_FOLDS
from cobot_calib_ros.core.kinematics.identification.gates import (MAX_DEVIATION_M,
                                                                   MAX_DEVIATION_RAD, Verdict)

MODELS = ('offsets', 'full', 'mdh', 'offsets+compliance', 'full+compliance',
          'mdh+compliance')
MAX_CORRELATED_LINES = 10


def add_arguments(p) -> None:
    p.add_argument('--measurement', choices=('spheres', 'points', 'pose', 'plane'),
                   default=None, help='identify offline from --source, a measurement file '
                   '(CSV + YAML sidecar, README "Measurement files") or a MUKCa folder')
    p.add_argument('--base-link', default=None,
                   help='--urdf: the chain\'s first link (default: the sidecar\'s frames.base)')
    p.add_argument('--tip-link', default=None,
                   help='--urdf: the chain\'s last link (default: the sidecar\'s frames.tip)')
    p.add_argument('--dh', default=None, help='a DH table (YAML) instead of --urdf')
    p.add_argument('--model', choices=MODELS, default=None,
                   help='error model: offsets (one per joint, any robot), full (--urdf: '
                        'every joint origin; its default), mdh (--dh: every DH row; its '
                        'default); +compliance adds a joint deflection in proportion to its '
                        'gravity torque')
    p.add_argument('--max-deviation-mm', type=float, default=MAX_DEVIATION_M * 1e3,
                   metavar='MM', help='the most a length of the model may move from nominal '
                   f'[mm] (default {MAX_DEVIATION_M * 1e3:g}); a parameter that ends there is '
                   'not determined by the data and the result is refused')
    p.add_argument('--max-deviation-mrad', type=float, default=MAX_DEVIATION_RAD * 1e3,
                   metavar='MRAD', help='the same for angles and zero offsets [mrad] (default '
                   f'{MAX_DEVIATION_RAD * 1e3:g})')
    held = p.add_mutually_exclusive_group()
    held.add_argument('--folds', type=int, default=None, metavar='K',
                      help=f'k-fold validation, row i in fold i %% K (default {DEFAULT_FOLDS})')
    held.add_argument('--leave-out', default=None, metavar='COLUMN',
                      help='hold out one group (a value of COLUMN) at a time')


def run(args) -> int:
    from cobot_calib_ros.core.errors import Refusal
    try:
        report = identify(args)
    except Refusal as e:
        return fail(f'identify {args.source}: {e}', EXIT_FAILED)
    except ValueError as e:
        return fail(f'identify: {e}', EXIT_USAGE)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print(summary(report))
    if not report['verdict']['passed']:
        return fail(f'identify {args.source}: {verdict_of(report).line()}', EXIT_FAILED)
    return EXIT_OK


def identify(args) -> dict:
    """The report of the command line's data (api.identification.identify_file)."""
    from cobot_calib_ros.api.identification import identify_file
    for flag, value in (('--max-deviation-mm', args.max_deviation_mm),
                        ('--max-deviation-mrad', args.max_deviation_mrad)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f'{flag} must be a finite number > 0, got {value}')
    return identify_file(args.source, args.measurement, urdf=args.urdf,
                         base_link=args.base_link, tip_link=args.tip_link, dh=args.dh,
                         model=args.model, folds=args.folds, leave_out=args.leave_out,
                         ball=args.ball, loss=args.loss,
                         max_deviation=(args.max_deviation_mm * 1e-3,
                                        args.max_deviation_mrad * 1e-3))


def summary(report: dict) -> str:
    """The report as a few lines of text."""
    v = report['validation']
    how = f'leave one {v["leave_out"]} out' if 'leave_out' in v else f'{v["folds"]}-fold'
    lines = [f'{report["robot"]}, {report["measurement"]} ({report["samples"]} samples), '
             f'model {report["model"]}: {report["parameters_kept"]} parameters kept '
             f'(textbook minimum {report["parameters_minimum"]}), condition number '
             f'{report["condition_number"]:.1f}, converged: '
             f'{"yes" if report["converged"] else "NO"}',
             f'held out ({how}) {"rmse":>8} {"mean":>8} {"max":>8} {"rot rms":>9}']
    for name in ('nominal', 'calibrated'):
        s = report['held_out'][name]
        rot = '' if s['rot_rms_mrad'] is None else f'{s["rot_rms_mrad"]:>6.2f} mrad'
        lines.append(f'{name:<{len(how) + 11}} {s["rmse_mm"]:>5.3f} mm {s["mean_mm"]:>5.3f} mm '
                     f'{s["max_mm"]:>5.3f} mm {rot}')
    verdict = verdict_of(report)
    lines.append('gate: passed (deviations within '
                 f'{report["bounds"]["length_mm"]:g} mm / {report["bounds"]["angle_mrad"]:g} '
                 'mrad, held out no worse than nominal)' if verdict.passed else
                 f'gate: {verdict.line()}')
    for d in report['dropped']:
        lines.append(f'dropped {d["name"]}: {d["reason"]}')
    parameters = {p['name'] for p in report['identified']}
    pairs = [c for c in report['correlated'] if c['a'] in parameters or c['b'] in parameters]
    for c in pairs[:MAX_CORRELATED_LINES]:
        lines.append(f'correlated {c["a"]} ~ {c["b"]}: {c["correlation"]:+.3f}')
    hidden = len(report['correlated']) - min(len(pairs), MAX_CORRELATED_LINES)
    if hidden:
        lines.append(f'{hidden} more correlated pairs (of the frames and targets, or past the '
                     f'first {MAX_CORRELATED_LINES}): --json lists them')
    for o in report['outliers']:
        lines.append(f'outlier: sample {o["sample"]} ({o["error_mm"]:.3f} mm)')
    return '\n'.join(lines)


def verdict_of(report: dict) -> Verdict:
    """The gates' verdict of a report (its JSON form back)."""
    return Verdict(tuple(report.get('verdict', {}).get('problems', ())))
