"""Simulator settings: the keys of ``fusion-eval simulate --set``, in the filter configuration's units,
and the sensor-grade presets of ``--grade``."""

from __future__ import annotations

from ..spec import S, Spec

def sim_schema() -> dict[str, Spec]:
    """The simulator's settings: the built-in sensors' (below) and those of the registered observations'
    simulated sensors (declared in their modules)."""
    from ..filters.observations import sim_keys

    return {**SIM_SCHEMA, **sim_keys()}


SIM_SCHEMA: dict[str, Spec] = {
    "imu.rate_hz": S(100.0, "IMU sample rate, Hz (10 to 400)", positive=True),
    "imu.accel_noise_mps2_sqrthz": S(0.001, "accelerometer white noise density, m/s^2/sqrt(Hz)", nonneg=True),
    "imu.gyro_noise_dps_sqrthz": S(0.005, "gyroscope white noise density, deg/s/sqrt(Hz)", nonneg=True),
    "imu.accel_bias_rw_mps3_sqrthz": S(3e-5, "accelerometer bias random walk, m/s^3/sqrt(Hz)", nonneg=True),
    "imu.gyro_bias_rw_dps2_sqrthz": S(1e-5, "gyroscope bias random walk, deg/s^2/sqrt(Hz)", nonneg=True),
    "imu.accel_bias_init_std_mps2": S(0.02, "std of the initial accelerometer bias (drawn once per axis), m/s^2", nonneg=True),
    "imu.gyro_bias_init_std_dps": S(0.05, "std of the initial gyroscope bias, deg/s", nonneg=True),
    "imu.bias_corr_time_s": S(0.0, "bias process: 0 = random walk; > 0 = first-order Gauss-Markov with this correlation "
                                   "time (s), driven by the *_bias_rw_* densities", nonneg=True),
    "imu.accel_lag_s": S(0.0, "the accelerometer reports the specific force of accel_lag_s earlier (a latency), s", nonneg=True),
    "imu.gyro_lag_s": S(0.0, "the gyro reports the rate of gyro_lag_s earlier (KITTI's OXTS: about 60 ms), s", nonneg=True),
    "imu.scale_factor_std_ppm": S(0.0, "std of the accelerometer and gyro scale-factor errors (drawn once per axis), ppm", nonneg=True),
    "gnss.rate_hz": S(1.0, "GNSS fix rate, Hz", positive=True),
    "gnss.noise_std_m": S([1.0, 1.0, 2.0], "GNSS white noise per axis E/N/U, m", nonneg=True),
    "gnss.outages_s": S([], "GNSS outage windows [[start, end], ...], s from the start", "windows"),
    "gnss.jumps": S([], "GNSS jumps [[start, end, dE, dN, dU], ...]: an offset (m) added inside the window", "jumps"),
    "odometer.rate_hz": S(10.0, "wheel-odometer rate, Hz", positive=True),
    "odometer.scale": S(1.005, "true odometer scale (measured speed = scale x true speed)", positive=True),
    "odometer.noise_std_mps": S(0.05, "odometer speed white noise, m/s", nonneg=True),
    "lidar.mode": S("odometry", "'odometry' (increments with noise and drift, integrated, KITTI poses in cam0) or "
                                "'map_matching' (absolute world poses with white noise, TUM)",
                    choices=("odometry", "map_matching")),
    "lidar.rate_hz": S(10.0, "lidar frame rate, Hz", positive=True),
    "lidar.pos_noise_std_m": S(0.02, "position noise per increment (odometry) or per pose (map matching), m", nonneg=True),
    "lidar.att_noise_std_deg": S(0.05, "attitude noise per increment or per pose, deg", nonneg=True),
    "lidar.scale_drift": S(0.005, "odometry: fractional scale error of the translation increments", nonneg=True),
    "lidar.yaw_drift_deg_per_100m": S(0.3, "odometry: yaw drift added per 100 m travelled, deg", nonneg=True),
    "lidar.time_offset_s": S(0.0, "the lidar stamps are written this much early (true time = stamp + offset): the "
                                  "filter's lidar.time_offset_s that corrects it, s (within +/-10 s: an offset of 1e6 s "
                                  "wrote a lidar stream that no run can use)", above=-10.0, below=10.0),
    "lidar.extrinsic_error_rpy_mrad": S([0.0, 0.0, 0.0], "rotation of the true lidar mount against the calibration file "
                                                          "written (roll, pitch, yaw about the IMU axes), mrad", "vec3"),
    "lidar.extrinsic_error_m": S([0.0, 0.0, 0.0], "lever-arm error of the calibration file written (IMU axes), m", "vec3"),
    "lidar.outlier_prob": S(0.0, "map matching: probability that a pose is an outlier (0 to 1)", nonneg=True),
    "lidar.outlier_std_m": S(3.0, "map matching: position std of outliers, m", nonneg=True),
    "origin.lat_deg": S(49.0, "geodetic origin of the local ENU frame: latitude, deg"),
    "origin.lon_deg": S(8.4, "longitude, deg"),
    "origin.alt_m": S(116.0, "ellipsoidal height, m (-1 km to 100 km, the heights a run accepts: a height of 1e9 m "
                              "was blamed on the IMU settings)", above=-1000.0, below=1e5),
    "start.posix_s": S(1767225600.0, "time of the first sample, POSIX seconds, 0 to 4e9 (written as a KITTI local-clock stamp)",
                       nonneg=True),
    "output.layout": S("kitti", "'kitti' (one file per OXTS packet, as KITTI raw), 'csv' (all packets in oxts/packets.csv), "
                                "'euroc' (an ASL folder), 'csv_log' (one generic CSV per stream), 'rosbag1' or 'rosbag2' "
                                "(one bag with every stream)",
                       choices=("kitti", "csv", "euroc", "csv_log", "rosbag1", "rosbag2")),
}

GRADES: dict[str, dict] = {
    # Typical figures, rounded; what a datasheet of each class states.
    "consumer": {"imu": {"accel_noise_mps2_sqrthz": 0.003, "gyro_noise_dps_sqrthz": 0.015,
                         "accel_bias_rw_mps3_sqrthz": 1e-4, "gyro_bias_rw_dps2_sqrthz": 5e-5,
                         "accel_bias_init_std_mps2": 0.05, "gyro_bias_init_std_dps": 0.2},
                 "gnss": {"noise_std_m": [2.0, 2.0, 4.0]}},
    "automotive": {"imu": {"accel_noise_mps2_sqrthz": 0.001, "gyro_noise_dps_sqrthz": 0.005,
                           "accel_bias_rw_mps3_sqrthz": 3e-5, "gyro_bias_rw_dps2_sqrthz": 1e-5,
                           "accel_bias_init_std_mps2": 0.02, "gyro_bias_init_std_dps": 0.05},
                   "gnss": {"noise_std_m": [1.0, 1.0, 2.0]}},
    "tactical": {"imu": {"accel_noise_mps2_sqrthz": 3e-4, "gyro_noise_dps_sqrthz": 0.0025,
                         "accel_bias_rw_mps3_sqrthz": 1e-5, "gyro_bias_rw_dps2_sqrthz": 1e-6,
                         "accel_bias_init_std_mps2": 0.005, "gyro_bias_init_std_dps": 0.001},
                 "gnss": {"noise_std_m": [0.5, 0.5, 1.0]}},
    "oxts-rt3003": {"imu": {"accel_noise_mps2_sqrthz": 5e-4, "gyro_noise_dps_sqrthz": 0.0035,
                            "accel_bias_rw_mps3_sqrthz": 1e-5, "gyro_bias_rw_dps2_sqrthz": 2e-6,
                            "accel_bias_init_std_mps2": 0.002, "gyro_bias_init_std_dps": 0.0006},
                    "gnss": {"noise_std_m": [0.3, 0.3, 0.6]}},
    "ideal": {"imu": {"accel_noise_mps2_sqrthz": 0.0, "gyro_noise_dps_sqrthz": 0.0, "accel_bias_rw_mps3_sqrthz": 0.0,
                      "gyro_bias_rw_dps2_sqrthz": 0.0, "accel_bias_init_std_mps2": 0.0, "gyro_bias_init_std_dps": 0.0},
              "gnss": {"noise_std_m": [0.0, 0.0, 0.0]},
              "odometer": {"scale": 1.0, "noise_std_mps": 0.0},
              "lidar": {"pos_noise_std_m": 0.0, "att_noise_std_deg": 0.0, "scale_drift": 0.0, "yaw_drift_deg_per_100m": 0.0}},
}
