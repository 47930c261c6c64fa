"""The HTTP side: the Flask app and gunicorn config of the HTTP workers. Imports no rclpy."""
