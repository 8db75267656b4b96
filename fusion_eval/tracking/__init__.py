"""2-D target tracking: a constant-velocity Kalman filter fusing lidar (linear) and radar (EKF) measurements."""
