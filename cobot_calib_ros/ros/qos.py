"""The QoS profiles of the suite's topics, in one place."""
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

# Results for late joiners (user_frame, repeatability): the last one, kept for new subscribers.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)

# 1 kHz joint_states: reliable so a capture window loses nothing; depth absorbs bursts.
JOINT_STATES = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)

# probe/voltage: best effort like any sensor stream (bags record it so), with a history that
# holds the burst a starved publisher catches up with (mock_robot.PROBE_BACKLOG, 3 s at 1 kHz);
# sensor_data's 5 lost most of such a burst.
PROBE_READINGS = QoSProfile(depth=3000, reliability=ReliabilityPolicy.BEST_EFFORT)
