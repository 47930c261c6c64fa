"""The wire between the HTTP workers (and the supervisor, and the probe) and the ROS worker.

See ``ipc/PROTOCOL.md`` for the messages. Nothing here imports rclpy.
"""
