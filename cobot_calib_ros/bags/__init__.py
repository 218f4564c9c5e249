"""rosbag2 bags without rosbag2: write (mcap), read (mcap and sqlite3, through rosbags), info,
and the rclpy nodes that record and replay them (recorder, player).

writer, reader, info, metadata and interfaces never import rclpy; player and recorder do.
"""
