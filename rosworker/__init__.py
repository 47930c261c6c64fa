"""The ROS worker: the only process of the gateway that uses rclpy."""
