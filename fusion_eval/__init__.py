"""fusion-eval: offline Kalman-filter fusion of IMU, GNSS and lidar odometry, evaluated with evo."""

__version__ = "0.1.0"
