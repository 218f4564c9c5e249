"""The QoS profiles of the suite's topics, in one place."""
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

# Results for late joiners (user_frame, repeatability): the last one, kept for new subscribers.
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)

# 1 kHz joint_states: reliable so a capture window loses nothing; depth absorbs bursts.
JOINT_STATES = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
