"""The supervisor: the gateway's main process (``sovd-gateway``), and the operator's probe.

``cli.py`` reads the settings and runs :class:`~supervisor.supervisor.Supervisor`, which starts
the ROS worker and gunicorn (``children.py``), restarts the ROS worker and speaks systemd's
notify protocol (``sdnotify.py``).  ``probe.py`` is ``sovd-probe``, the operator's command line
to the ROS worker's socket.  Imports no rclpy, and nothing of the HTTP side.
"""
