"""The constant-acceleration motion model: Kalman filter, RTS smoother and its factor-graph twin."""
