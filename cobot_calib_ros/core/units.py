"""Lengths are metres everywhere (names ending _mm aside): the bound that tells millimetres."""

MAX_CELL_LENGTH = 10.0
"""[m] No point of a cobot cell (a marker, a tool, a sphere, a camera, a touched point) is this
far from the origin of the frame it is given in: a larger length is millimetres."""
