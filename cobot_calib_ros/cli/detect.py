"""`cobot-calib detect`: find ArUco / AprilTag markers and ChArUco boards in still images.

Per image: each marker's id and four corners in raw-image pixels, and, given the camera's
intrinsics (--camera-info) and the marker length (--marker-length) or a board (--board), the
pose of the marker / board in the camera's optical frame. No ROS graph is needed.
"""
from __future__ import annotations

import argparse
from pathlib import Path
import textwrap

from cobot_calib_ros.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, fail, print_message

DEFAULT_DICTIONARY = 'DICT_6X6_250'
CONVENTIONS = (
    'pixels: OpenCV convention on the raw image (x right, y down, origin at the centre of the '
    'top-left pixel); corners: top-left, top-right, bottom-right, bottom-left of the marker as '
    'printed. Poses T_optical_<target> in the optical frame (x right, y down, z forward) [m, '
    'rad]; marker frame: centre, x right, y up, z out of the face; board frame: top-left outer '
    'corner of the square grid, x right, y down, z into the board. rpy: roll, pitch, yaw '
    '[deg] with R = Rz(yaw) Ry(pitch) Rx(roll).')

EPILOG = """\
examples:
  cobot-calib detect photo.png
  cobot-calib detect shot*.png --camera-info camera.yaml --marker-length 0.05 --json
  cobot-calib detect board.jpg --camera-info camera.yaml \\
      --board charuco:squares=5x7,square=0.04,marker=0.02,dict=DICT_6X6_250 --annotate out.png

--board SPEC: charuco:squares=COLSxROWS,square=M,marker=M,dict=NAME[,legacy=1][,first=ID]
  lengths in metres; legacy=1 for boards made by OpenCV < 4.6 with an even number of rows;
  first=ID when the board's marker ids do not start at 0.
--camera-info: ROS camera_calibration YAML, a CameraInfo message as `ros2 topic echo --once`
  prints it, or OpenCV FileStorage YAML (camera_matrix, distortion_coefficients). Poses use K
  and D of the raw image (not the projection matrix P).

""" + textwrap.fill(CONVENTIONS, 92)


def add_parser(subparsers):
    p = subparsers.add_parser(
        'detect', help='find markers / ChArUco boards in images; corners and poses',
        description=__doc__.strip(),
        epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument('images', nargs='+', metavar='IMAGE', help='image files (any format OpenCV '
                   'reads; EXIF orientation is ignored: pixels as stored)')
    p.add_argument('--camera-info', metavar='YAML', help='intrinsics of the raw image (for poses)')
    p.add_argument('--cell', metavar='NAME', help="without --camera-info: the cell camera's "
                   'active intrinsics record (cobot-calib intrinsics) in --data-dir')
    p.add_argument('--data-dir', help='results root of --cell (default $COBOT_CALIB_DATA or '
                   '~/.ros/cobot_calib)')
    p.add_argument('--dictionary', metavar='NAME',
                   help='marker dictionary, e.g. DICT_4X4_50, DICT_APRILTAG_36h11 '
                        f'(case-insensitive; default: the board\'s, else {DEFAULT_DICTIONARY})')
    p.add_argument('--marker-length', type=float, metavar='M',
                   help='side of the markers\' black square [m] (for their poses)')
    p.add_argument('--board', metavar='SPEC', help='a ChArUco board (see below)')
    p.add_argument('--refine', choices=('edges', 'subpix', 'apriltag', 'none'), default='edges',
                   help='corner refinement (default edges: lines fitted to the marker sides; '
                        'apriltag is slow)')
    p.add_argument('--annotate', metavar='OUT.png', help='write the image with markers, board '
                   'corners and axes drawn; with several images OUT-<i>.png, i from 0')
    p.add_argument('--json', action='store_true', help='one JSON object per image')
    return p


class _Setup:
    """What every image shares: validated arguments, built once."""

    def __init__(self, args):
        from cobot_calib_ros.core.landmarks.camera import CameraInfoError
        from cobot_calib_ros.loaders import load_camera_info_yaml
        from cobot_calib_ros.core.landmarks.targets import (MAX_LENGTH_M, BoardSpec,
                                                            canonical_dictionary_name)
        self.args = args
        self.board = None
        if args.board is not None:
            try:
                self.board = BoardSpec.parse(args.board)
            except ValueError as e:
                raise UsageError(f'bad --board: {e}') from None
        try:
            self.dictionary = canonical_dictionary_name(
                args.dictionary or (self.board.dictionary if self.board else DEFAULT_DICTIONARY))
        except ValueError as e:
            raise UsageError(f'bad --dictionary: {e}') from None
        length = args.marker_length
        if length is not None and not (0.0 < length <= MAX_LENGTH_M):
            raise UsageError(f'bad --marker-length {length:g}: the side in metres, '
                             f'0 < M <= {MAX_LENGTH_M:g} (0.05 for 50 mm)')
        self.camera = None
        if args.camera_info is not None:
            try:
                self.camera = load_camera_info_yaml(args.camera_info)
            except CameraInfoError as e:
                raise UsageError(f'bad --camera-info: {e}') from None
        elif args.cell is not None:
            self.camera = _active_intrinsics(args.cell, args.data_dir)
        elif length is not None:
            raise UsageError('--marker-length gives marker poses, which need --camera-info YAML')
        if args.annotate is not None:
            import cv2
            out = Path(args.annotate)
            if not out.parent.is_dir():
                raise UsageError(f'bad --annotate: no folder {out.parent}')
            if not cv2.haveImageWriter(str(out)):
                kind = out.suffix or 'files without an extension'
                raise UsageError(f'bad --annotate: OpenCV cannot write {kind}; use .png or .jpg')
        from cobot_calib_ros.core.landmarks.pipeline import Pipeline
        # markers of the board (same dictionary, its id range) get the board's pose only
        self.pipeline = Pipeline(self.dictionary, self.board, marker_length=args.marker_length,
                                 refine=args.refine)

    def annotate_path(self, index: int) -> Path:
        out = Path(self.args.annotate)
        n = len(self.args.images)
        if n == 1:
            return out
        return out.with_name(f'{out.stem}-{index:0{len(str(n - 1))}d}{out.suffix}')


class UsageError(Exception):
    pass


def _active_intrinsics(cell_name: str, data_dir: str | None):
    """The CameraModel of the cell camera's active intrinsics record; UsageError if none."""
    from cobot_calib_ros import paths, store
    from cobot_calib_ros.core.cell import CellFileError
    from cobot_calib_ros.loaders import load_cell
    from cobot_calib_ros.store.cells import ResultsCell
    from cobot_calib_ros.store.rigs import active_set
    try:
        cell = load_cell(paths.cell_file(cell_name))
    except CellFileError as e:
        raise UsageError(f'bad --cell: {e}') from None
    if cell.camera is None:
        raise UsageError(f'bad --cell: cell {cell.name!r} has no camera')
    active = active_set(store.open(paths.data_dir(data_dir), cell=ResultsCell.of(cell)),
                        cell).intrinsics
    if active is None:
        raise UsageError(f'cell {cell.name!r} has no active intrinsics for '
                         f'{cell.camera.frame_id}; run cobot-calib intrinsics or give '
                         '--camera-info')
    return active.model


def run(args) -> int:
    try:
        setup = _Setup(args)
    except UsageError as e:
        return fail(str(e), EXIT_USAGE)
    if not args.json:
        print(textwrap.fill(CONVENTIONS, 92) + '\n', flush=True)
    failed = 0
    for index, path in enumerate(args.images):
        try:
            result = _process(setup, index, path)
        except ImageFailure as e:
            failed += 1
            fail(f'detect: {path}: {e}')
            if args.json:
                print_message({'image': path, 'error': str(e)}, True)
            continue
        if args.json:
            print_message(result, True)
        else:
            _print_text(result)
    return EXIT_FAILED if failed else EXIT_OK


class ImageFailure(Exception):
    pass


def read_image(path: str):
    """bgr8 pixels as stored (EXIF orientation ignored); ImageFailure says why not."""
    import cv2
    import numpy as np
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except (OSError, ValueError) as e:
        raise ImageFailure(f'cannot read: {getattr(e, "strerror", None) or e}') from None
    if data.size == 0:
        raise ImageFailure('the file is empty')
    image = cv2.imdecode(data, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    if image is None or image.size == 0:
        raise ImageFailure('not an image OpenCV can decode (corrupt or unsupported format)')
    return image


def _pose_dict(pose, frame: str) -> dict:
    import numpy as np
    from scipy.spatial.transform import Rotation
    R = Rotation.from_matrix(pose.T_optical_target[:3, :3])
    out = {
        'frame': frame,
        'translation': [round(float(v), 6) for v in pose.tvec],
        'rotation_vector': [round(float(v), 6) for v in pose.rvec],
        'rpy_deg': [round(float(v), 4) for v in np.degrees(R.as_euler('xyz'))],
        'quaternion_xyzw': [round(float(v), 7) for v in R.as_quat()],
        'rms_px': round(pose.rms_px, 4),
        'sigma_px': round(pose.sigma_px, 4),
        'covariance': [[float(f'{v:.6g}') for v in row] for row in pose.covariance],
    }
    ratio = pose.ambiguity_ratio
    if ratio is not None:
        out['mirror_ratio'] = round(ratio, 3) if np.isfinite(ratio) else None
        out['ambiguous'] = pose.ambiguous
    return out


def _process(setup: _Setup, index: int, path: str) -> dict:
    args, camera = setup.args, setup.camera
    image = read_image(path)
    h, w = image.shape[:2]
    wrong_size = camera.size_problem(image.shape) if camera is not None else None
    if wrong_size is not None:
        raise ImageFailure(wrong_size.message + ' (--camera-info)')
    result = {'image': path, 'width': w, 'height': h, 'dictionary': setup.dictionary,
              'refine': args.refine, 'markers': []}
    found = setup.pipeline.detect(image, camera)
    markers, board, poses = [m for m, _ in found.markers], found.board, []
    for m, pose in found.markers:
        entry = {'id': m.id, 'corners': [[round(float(x), 3), round(float(y), 3)]
                                         for x, y in m.corners], 'refinement': m.refinement}
        if m.id in setup.pipeline.board_ids:
            entry['board'] = True
        elif pose is not None:
            entry['pose'] = _pose_dict(pose, 'T_optical_marker')
            poses.append((pose, args.marker_length / 2))
        elif m.id in found.pose_errors:
            entry['pose_error'] = found.pose_errors[m.id]
        result['markers'].append(entry)
    if board is not None:
        spec = setup.board
        out = {'spec': str(spec), 'n_markers': len(board.markers),
               'charuco_ids': [int(i) for i in board.charuco_ids],
               'charuco_corners': [[round(float(x), 3), round(float(y), 3)]
                                   for x, y in board.charuco_corners]}
        if found.board_pose is not None:
            out['pose'] = _pose_dict(found.board_pose, 'T_optical_board')
            poses.append((found.board_pose, 2 * spec.square_length))
        elif 'board' in found.pose_errors:
            out['pose_error'] = found.pose_errors['board']
        result['board'] = out
    if args.annotate is not None:
        target = setup.annotate_path(index)
        _annotate(image, markers, board, camera, poses, target)
        result['annotated'] = str(target)
    return result


def _annotate(image, markers, board, camera, poses, target: Path) -> None:
    import cv2
    import numpy as np
    out = image.copy()
    if markers:
        cv2.aruco.drawDetectedMarkers(out, [m.corners.reshape(1, 4, 2).astype(np.float32)
                                            for m in markers],
                                      np.array([[m.id] for m in markers], dtype=np.int32))
    if board is not None and len(board):
        cv2.aruco.drawDetectedCornersCharuco(
            out, board.charuco_corners.reshape(-1, 1, 2).astype(np.float32),
            board.charuco_ids.reshape(-1, 1).astype(np.int32), (255, 0, 255))
    for pose, length in poses:
        axes = np.array([[0, 0, 0], [length, 0, 0], [0, length, 0], [0, 0, length]], float)
        px = camera.project(axes, pose.rvec, pose.tvec)
        if not np.all(np.isfinite(px)) or np.abs(px).max() > 1e5:
            continue
        o = tuple(int(round(v)) for v in px[0])
        for k, colour in ((1, (0, 0, 255)), (2, (0, 255, 0)), (3, (255, 0, 0))):  # x y z: RGB
            cv2.line(out, o, tuple(int(round(v)) for v in px[k]), colour, 2, cv2.LINE_AA)
    try:
        ok = cv2.imwrite(str(target), out)
    except cv2.error as e:
        raise ImageFailure(f'cannot write {target}: {e.err}') from None
    if not ok:
        raise ImageFailure(f'cannot write {target}')


def _fmt(values, digits: int) -> str:
    return '(' + ', '.join(f'{v:.{digits}f}' for v in values) + ')'


def _pose_text(pose: dict) -> str:
    import numpy as np
    sd = np.sqrt(np.clip(np.diag(np.array(pose['covariance'])), 0, None))
    text = (f'{pose["frame"]}: xyz {_fmt(pose["translation"], 4)} m, rotvec '
            f'{_fmt(pose["rotation_vector"], 4)} rad, rpy {_fmt(pose["rpy_deg"], 2)} deg; '
            f'rms {pose["rms_px"]:.3f} px; 1-sigma {_fmt(sd[:3] * 1000, 2)} mm, '
            f'{_fmt(np.degrees(sd[3:]), 3)} deg')
    if 'mirror_ratio' in pose:
        ratio = pose['mirror_ratio']
        text += f'; mirror ratio {"inf" if ratio is None else f"{ratio:.1f}"}'
        if pose['ambiguous']:
            text += ' (AMBIGUOUS: the flipped pose fits almost as well)'
    return text


def _print_text(result: dict) -> None:
    fallback = sum(m['refinement'] != result['refine'] for m in result['markers'])
    print(f'{result["image"]}: {result["width"]}x{result["height"]}, '
          f'{len(result["markers"])} marker(s) of {result["dictionary"]} '
          f'(refine {result["refine"]})')
    if fallback:
        print(f'  {fallback} of {len(result["markers"])} marker(s) kept sub-pixel corners: '
              f'their edges could not be fitted (too small, an edge missing or unclear); '
              f'marked [subpix]')
    for m in result['markers']:
        corners = ' '.join(_fmt(c, 2) for c in m['corners'])
        tags = ('  [board]' if m.get('board') else '') + \
            (f'  [{m["refinement"]}]' if m['refinement'] != result['refine'] else '')
        print(f'  id {m["id"]:>4}: {corners}{tags}')
        if 'pose' in m:
            print(f'        {_pose_text(m["pose"])}')
        elif 'pose_error' in m:
            print(f'        no pose: {m["pose_error"]}')
    board = result.get('board')
    if board is not None:
        print(f'  board {board["spec"]}: {len(board["charuco_ids"])} corner(s) from '
              f'{board["n_markers"]} marker(s)')
        if 'pose' in board:
            print(f'        {_pose_text(board["pose"])}')
        elif 'pose_error' in board:
            print(f'        no pose: {board["pose_error"]}')
    if 'annotated' in result:
        print(f'  annotated: {result["annotated"]}')
    print(flush=True)
