"""Strapdown mechanization and Kalman filters (numba kernels for the per-IMU-sample work)."""
