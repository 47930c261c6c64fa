"""The HTTP side (Flask app, gunicorn config) and the supervisor. Imports no rclpy."""
