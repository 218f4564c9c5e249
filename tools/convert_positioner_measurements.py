"""Convert ROS-Industrial industrial_calibration's two-axis positioner data
(examples/data/kinematic_calibration/measurements.yaml) to a measurement CSV (README,
"Measurement files"): one row per entry, in timestamp order.

    python tools/convert_positioner_measurements.py measurements.yaml OUT.csv
"""
import csv
import sys

import yaml


def main(source: str, out: str) -> None:
    entries = yaml.safe_load(open(source, encoding='utf-8'))
    with open(out, 'w', newline='', encoding='utf-8') as f:
        w = csv.writer(f)
        w.writerow(['stamp', 'joint_1', 'joint_2', 'x', 'y', 'z', 'qw', 'qx', 'qy', 'qz'])
        for stamp in sorted(entries, key=int):
            e = entries[stamp]
            p = e['pose']
            w.writerow([stamp, *e['target_joints'], p['x'], p['y'], p['z'], p['qw'], p['qx'],
                        p['qy'], p['qz']])


if __name__ == '__main__':
    main(*sys.argv[1:3])
