"""cobot_calib_ros: live calibration of a collaborative-robot cell on ROS 2 Jazzy."""
import os

# One BLAS thread unless the user chose otherwise; read when numpy loads, so this holds in every
# process that imports the package first (the CLI, the nodes, make bench). The suite runs many
# processes on a few cores, and its matrices are tall and thin (identification Jacobians): there
# OpenBLAS's threads only wait for each other. An SVD of 1500 x 57 took 166 ms with the default
# threads at a load of 8 on 2 cores, 3.7 ms with one; the bench's kinematic identification
# 23 s -> 1.9 s.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')
