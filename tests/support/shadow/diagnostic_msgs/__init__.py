"""Shadows the real diagnostic_msgs package for a ROS worker started with this
directory on PYTHONPATH: the worker then behaves as on a robot where the
package is not installed (its topics are served as metadata only)."""

raise ImportError("diagnostic_msgs is hidden for this test")
