"""ISO 9283 repeatability: the first paper's statistics (iso9283) and trial procedure (trial)."""
from cobot_calib_ros.core.repeatability.iso9283 import (
    AXES, complete_cycles, correct_distance, deviations, Direction, DIRECTIONS,
    iso9283_rp_3d, iso9283_rp_from_axes, overall_rp, point_statistics, PointStats,
    probe_offset, range_correction, RangeCorrection)

__all__ = ['AXES', 'complete_cycles', 'correct_distance', 'deviations', 'Direction',
           'DIRECTIONS', 'iso9283_rp_3d', 'iso9283_rp_from_axes', 'overall_rp',
           'point_statistics', 'PointStats', 'probe_offset', 'range_correction',
           'RangeCorrection']
