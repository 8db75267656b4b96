"""``fusion-eval track`` and ``simulate-track``: a 2-D target tracked with lidar (KF) and radar (EKF)."""

from __future__ import annotations

import math
from pathlib import Path

from ..errors import ConfigError, OutputError
from ..outputs import StagedDir, atomic_file


def _positive(name: str, v: float) -> None:
    if not (math.isfinite(v) and v > 0):
        raise ConfigError(f"{name} must be a finite number > 0, got {v}")


def track(input_path: Path, out_dir: Path, sensors: str, noise_ax: float, noise_ay: float, lidar_var, radar_var,
          overwrite: bool = False, make_plots: bool = True, smooth: bool = False, max_gap_s: float = 5.0) -> dict:
    """Run the tracker on a measurement file and write its outputs; returns the metrics."""
    from ..tracking.ekf import TrackParams, run_track
    from ..tracking.ekf import smooth as rts
    from ..tracking.measurements import read_measurements
    from ..tracking.report import write_track_outputs

    for name, v in (("--noise-ax", noise_ax), ("--noise-ay", noise_ay), *(("--lidar-var", x) for x in lidar_var),
                    *(("--radar-var", x) for x in radar_var), ("--max-gap", max_gap_s)):
        _positive(name, v)
    params = TrackParams(noise_ax=noise_ax, noise_ay=noise_ay, lidar_var=tuple(lidar_var), radar_var=tuple(radar_var),
                         sensors=sensors, max_gap_s=max_gap_s)
    staged = StagedDir(out_dir, overwrite=overwrite, inputs=(input_path,))
    staged.check()
    m = read_measurements(input_path)
    res = run_track(m, params)
    if smooth:
        res = rts(res)
    with staged as out:
        return write_track_outputs(out, res, params, str(input_path), make_plots)


MAX_TRACK_MEASUREMENTS = 10_000_000


def simulate_track(out_file: Path, duration_s: float, interval_s: float, seed: int, start, heading_deg: float,
                   speed_mps: float, overwrite: bool = False, progress=None) -> int:
    """Write a measurement file with known truth; returns the number of measurements. ``progress(done, total)`` is
    called after each chunk of lines (10 million take minutes)."""
    from ..tracking.simulate import simulate_track_chunks

    if not (duration_s > 0 and interval_s > 0 and math.isfinite(duration_s) and math.isfinite(interval_s)):
        raise ConfigError("--duration and --interval must be finite numbers > 0")
    n = duration_s / interval_s
    if not 2 <= n <= MAX_TRACK_MEASUREMENTS:     # one empty line; or 7 PiB asked of numpy for 1e12 s
        raise ConfigError(f"--duration / --interval must give 2 to {MAX_TRACK_MEASUREMENTS:,} measurements, got {n:.3g}")
    if seed < 0:
        raise ConfigError(f"--seed must be >= 0, got {seed}")
    for name, v in (("--start", start[0]), ("--start", start[1]), ("--heading", heading_deg), ("--speed", speed_mps)):
        if not (math.isfinite(v) and abs(v) <= 1e6):   # the measurement file would hold nan, which track refuses
            raise ConfigError(f"{name} must be a finite number (at most 1e6 in size), got {v}")
    out_file = Path(out_file)
    if out_file.is_dir():
        raise ConfigError(f"{out_file}: is a folder (give a file name)")
    if out_file.exists() and not overwrite:
        raise ConfigError(f"{out_file}: exists (use --overwrite to replace it)")
    if not out_file.parent.is_dir():
        raise ConfigError(f"{out_file.parent}: folder not found")
    n_lines = 0
    try:
        # streamed a chunk at a time (10 million lines are 1.3 GB of text) into a file that appears when complete
        with atomic_file(out_file) as fh:
            for text in simulate_track_chunks(duration_s, interval_s, seed, start=tuple(start), speed_mps=speed_mps,
                                              heading0_rad=math.radians(heading_deg)):
                fh.write(text.encode())
                n_lines += text.count("\n")
                if progress is not None:
                    progress(n_lines, int(round(n)))
    except OSError as exc:
        raise OutputError(f"{out_file}: cannot write ({exc.strerror})") from None
    return n_lines
