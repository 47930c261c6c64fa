"""What all three processes share: settings, runtime files and process lifecycle helpers.

``settings.py`` (every gateway setting), ``runfiles.py`` (the runtime dir's shared files),
``pdeathsig.py`` (a child's parent-death signal).  Imports no rclpy and nothing of the
other packages.
"""
