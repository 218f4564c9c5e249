"""Fiducial targets: marker dictionaries by name and ChArUco boards from a compact spec string.

Frames (OpenCV's, published as they are):

- Single marker of side ``L`` [m]: origin at the marker centre, x right, y up, z out of the
  printed face. Corners top-left, top-right, bottom-right, bottom-left are
  (-L/2, L/2, 0), (L/2, L/2, 0), (L/2, -L/2, 0), (-L/2, -L/2, 0) (IPPE_SQUARE's object points).
- ChArUco board (OpenCV >= 4.6): origin at the top-left *outer* corner of the square grid as
  printed (the corner of the top-left square), x right along the ``squares_x`` columns, y down
  along the ``squares_y`` rows, z into the board (away from a camera that sees it). Chessboard
  corner ``i`` (the ChArUco id) lies at ((i % (squares_x - 1) + 1) * square,
  (i // (squares_x - 1) + 1) * square, 0).
"""
from __future__ import annotations

from dataclasses import dataclass
import difflib
import functools

import cv2
import numpy as np
from numpy.typing import NDArray


def _predefined() -> dict[str, int]:
    """Upper-case name -> cv2.aruco constant; one entry per dictionary (OpenCV also spells
    the AprilTag ones in lower case: DICT_APRILTAG_36h11 == DICT_APRILTAG_36H11)."""
    names = {}
    for attr in dir(cv2.aruco):
        if attr.startswith('DICT_') and isinstance(getattr(cv2.aruco, attr), int):
            names.setdefault(attr.upper(), getattr(cv2.aruco, attr))
    return names


PREDEFINED = _predefined()


def dictionary_names() -> list[str]:
    """The canonical names: DICT_4X4_50 ... DICT_APRILTAG_36H11 ... DICT_ARUCO_ORIGINAL."""
    return sorted(PREDEFINED)


def canonical_dictionary_name(name: str) -> str:
    """'dict_6x6_250', '6X6_250', 'DICT_APRILTAG_36h11', 'apriltag_36h11' -> the canonical name.

    ValueError for an unknown name, listing the close ones."""
    key = str(name).strip().upper().replace('-', '_')
    if not key.startswith('DICT_'):
        key = 'DICT_' + key
    if key in PREDEFINED:
        return key
    close = difflib.get_close_matches(key, PREDEFINED, n=4, cutoff=0.6)
    hint = (f'did you mean {", ".join(close)}?' if close else
            f'known: {", ".join(dictionary_names())}')
    raise ValueError(f'unknown marker dictionary {name!r}; {hint} (case-insensitive; '
                     f'the DICT_ prefix is optional)')


@functools.lru_cache(maxsize=None)
def get_dictionary(name: str) -> cv2.aruco.Dictionary:
    """The cv2.aruco predefined dictionary of that name (see canonical_dictionary_name)."""
    return cv2.aruco.getPredefinedDictionary(PREDEFINED[canonical_dictionary_name(name)])


def dictionary_size(dictionary: cv2.aruco.Dictionary) -> int:
    return int(dictionary.bytesList.shape[0])


def marker_object_points(length: float) -> NDArray[np.float64]:
    """(4, 3) corners [m] of a marker of side ``length`` in its frame (centre, x right, y up,
    z out), in OpenCV's corner order top-left, top-right, bottom-right, bottom-left."""
    h = float(length) / 2.0
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


_SPEC_KEYS = ('squares', 'square', 'marker', 'dict', 'legacy', 'first')
SPEC_EXAMPLE = 'charuco:squares=5x7,square=0.04,marker=0.02,dict=DICT_6X6_250'
MAX_LENGTH_M = 5.0     # a longer square or marker is a unit mistake (millimetres given)


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: ``squares_x`` x ``squares_y`` squares of side ``square_length`` [m]
    with markers of side ``marker_length`` [m] from ``dictionary``, ids from ``first_id``.

    ``legacy`` selects OpenCV's pre-4.6 pattern (matters only when squares_y is even: the
    old boards start with a marker in the top-left square only for odd rows). Frame: see the
    module docstring (origin at the grid's top-left outer corner, x right, y down, z in).
    """

    squares_x: int
    squares_y: int
    square_length: float
    marker_length: float
    dictionary: str = 'DICT_6X6_250'
    legacy: bool = False
    first_id: int = 0

    def __post_init__(self):
        object.__setattr__(self, 'dictionary', canonical_dictionary_name(self.dictionary))
        if self.squares_x < 2 or self.squares_y < 2:
            raise ValueError(f'a ChArUco board needs at least 2x2 squares, got '
                             f'{self.squares_x}x{self.squares_y}')
        if not (0 < self.marker_length < self.square_length):
            raise ValueError(f'need 0 < marker ({self.marker_length}) < square '
                             f'({self.square_length}) [m]')
        if self.square_length > MAX_LENGTH_M:
            raise ValueError(f'square = {self.square_length} m: lengths are metres '
                             f'(0.04 for 40 mm)')
        if self.first_id < 0:
            raise ValueError(f'first marker id must be >= 0, got {self.first_id}')
        available = dictionary_size(get_dictionary(self.dictionary))
        if self.first_id + self.n_markers > available:
            raise ValueError(f'a {self.squares_x}x{self.squares_y} board needs '
                             f'{self.n_markers} marker ids from {self.first_id}, but '
                             f'{self.dictionary} has {available} (ids 0..{available - 1})')

    @classmethod
    def parse(cls, spec: str) -> BoardSpec:
        """From ``charuco:squares=5x7,square=0.04,marker=0.02,dict=DICT_6X6_250`` (optional
        ``legacy=1`` for OpenCV's pre-4.6 pattern, ``first=ID`` for the first marker id;
        lengths in metres; squares = columns x rows). ValueError says what is wrong."""
        text = str(spec).strip()
        kind, sep, rest = text.partition(':')
        if not sep or kind.strip().lower() != 'charuco':
            raise ValueError(f'board spec {spec!r} must start with "charuco:", e.g. '
                             f'{SPEC_EXAMPLE}')
        fields = {}
        for item in filter(None, (s.strip() for s in rest.split(','))):
            key, eq, value = item.partition('=')
            key = key.strip().lower()
            if not eq or key not in _SPEC_KEYS:
                raise ValueError(f'board spec {spec!r}: {item!r} is not KEY=VALUE with KEY in '
                                 f'{", ".join(_SPEC_KEYS)}; e.g. {SPEC_EXAMPLE}')
            if key in fields:
                raise ValueError(f'board spec {spec!r}: {key} given twice')
            fields[key] = value.strip()
        missing = [k for k in ('squares', 'square', 'marker', 'dict') if k not in fields]
        if missing:
            raise ValueError(f'board spec {spec!r} lacks {", ".join(missing)}; e.g. '
                             f'{SPEC_EXAMPLE}')
        try:
            sx, sy = (int(v) for v in fields['squares'].lower().split('x'))
        except ValueError:
            raise ValueError(f'board spec {spec!r}: squares={fields["squares"]} is not '
                             f'COLUMNSxROWS such as 5x7') from None
        lengths = {}
        for key in ('square', 'marker'):
            try:
                lengths[key] = float(fields[key])
            except ValueError:
                raise ValueError(f'board spec {spec!r}: {key}={fields[key]} is not a length '
                                 f'in metres') from None
        flag = fields.get('legacy', '0').lower()
        if flag not in ('0', '1', 'true', 'false', 'yes', 'no'):
            raise ValueError(f'board spec {spec!r}: legacy={fields["legacy"]} is not 0 or 1')
        try:
            first = int(fields.get('first', '0'))
        except ValueError:
            raise ValueError(f'board spec {spec!r}: first={fields["first"]} is not a marker '
                             f'id') from None
        return cls(sx, sy, lengths['square'], lengths['marker'], fields['dict'],
                   flag in ('1', 'true', 'yes'), first)

    def __str__(self) -> str:
        extra = (',legacy=1' if self.legacy else '') + \
            (f',first={self.first_id}' if self.first_id else '')
        return (f'charuco:squares={self.squares_x}x{self.squares_y},'
                f'square={self.square_length:g},marker={self.marker_length:g},'
                f'dict={self.dictionary}{extra}')

    @property
    def n_markers(self) -> int:
        return self.squares_x * self.squares_y // 2

    @property
    def n_corners(self) -> int:
        return (self.squares_x - 1) * (self.squares_y - 1)

    @property
    def size(self) -> tuple[float, float]:
        """Width (x) and height (y) of the square grid [m]."""
        return self.squares_x * self.square_length, self.squares_y * self.square_length

    def corner_points(self) -> NDArray[np.float64]:
        """(n_corners, 3) chessboard corners [m] in the board frame, row i = ChArUco id i."""
        i = np.arange(self.n_corners)
        cols = self.squares_x - 1
        return np.stack([(i % cols + 1) * self.square_length,
                         (i // cols + 1) * self.square_length, np.zeros(len(i))], axis=1)

    def board(self) -> cv2.aruco.CharucoBoard:
        """The cv2.aruco.CharucoBoard (built once per spec)."""
        return _charuco_board(self)


@functools.lru_cache(maxsize=64)
def _charuco_board(spec: BoardSpec) -> cv2.aruco.CharucoBoard:
    ids = np.arange(spec.first_id, spec.first_id + spec.n_markers, dtype=np.int32)
    board = cv2.aruco.CharucoBoard((spec.squares_x, spec.squares_y), spec.square_length,
                                   spec.marker_length, get_dictionary(spec.dictionary), ids)
    board.setLegacyPattern(spec.legacy)
    return board
