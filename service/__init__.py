"""Track service: converted-measurement Kalman tracking over Eclipse Zenoh."""

__version__ = "0.1.0"
