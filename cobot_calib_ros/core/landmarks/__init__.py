"""Fiducial landmarks: ArUco / AprilTag markers and ChArUco boards, detected and posed in images.

Pure (OpenCV + numpy). Conventions, kept by every module here:

- Pixels: OpenCV's convention on the raw (unrectified) image: x right, y down, the origin at the
  *centre* of the top-left pixel (pixel centres at integer coordinates).
- Marker corners: top-left, top-right, bottom-right, bottom-left of the marker as printed
  (clockwise in the image when seen from the front).
- Marker frame (OpenCV, IPPE_SQUARE object points): origin at the marker centre, x right,
  y up, z out of the printed face (towards a camera that sees it).
- ChArUco board frame (OpenCV >= 4.6): origin at the top-left outer corner of the square grid,
  x right (along the squares_x columns), y down, z into the board.
- Poses are ``T_optical_target`` (see core/frames.py): the target frame in the camera's optical
  frame (x right, y down, z forward), metres and radians.
"""
