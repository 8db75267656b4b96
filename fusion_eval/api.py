"""The public Python API (exported by :mod:`fusion_eval`)::

    import fusion_eval as fe
    ds = fe.load_dataset("data/kitti-00")                      # a folder, a manifest file, or a raw KITTI drive
    res = fe.run(ds, overrides={"gnss.rate_hz": 2.0})          # in memory; writes nothing
    res.metrics                                                # the same nested dict as metrics.json
    res.trajectories["fused"]                                  # evo PoseTrajectory3D
    res.write("out/")                                          # exactly the files `fusion-eval run --out out/` writes
    fe.evaluate(reference, estimate, alignment="se3")          # trajectories or paths -> the metrics of `evaluate`

Overrides are plain Python values keyed by ``section.key`` (or nested ``{section: {key: value}}``); errors are
the package's exceptions (:class:`fusion_eval.errors.FusionEvalError` and subclasses) with the same one-line
messages as the command line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from . import session
from .outputs import StagedDir
from .pipeline import RunResult, execute
from .types import Dataset, PoseSeries


def _check_types(path=None, overrides=None, config=None, progress=None) -> None:
    """The API's arguments of the wrong kind as the package's own errors, not a TypeError or AttributeError from deep
    inside (``fe.run(None, overrides=[...])``, ``fe.load_dataset(5)``; an API review)."""
    from collections.abc import Mapping

    from .errors import ConfigError

    if path is not None and not isinstance(path, (str, Path, Dataset)):
        raise ConfigError(f"dataset: expected a path (str or Path), a Dataset or None, got {type(path).__name__}")
    if overrides is not None and not isinstance(overrides, Mapping):
        raise ConfigError(f"overrides: expected a mapping of keys to values ({{'gnss.rate_hz': 2.0}}), got "
                          f"{type(overrides).__name__}")
    if config is not None and not isinstance(config, (str, Path, Mapping)):
        raise ConfigError(f"config: expected a file path or a {{section: {{key: value}}}} mapping, got {type(config).__name__}")
    if progress is not None and not callable(progress):
        raise ConfigError(f"progress: expected a callable taking the fraction done, got {type(progress).__name__}")


def load_dataset(path: str | Path | None = None) -> Dataset:
    """A dataset: a folder holding ``dataset.yaml``, a manifest file, or a plain KITTI raw drive folder.
    ``None`` (or ``"data/kitti-00"`` outside a checkout) is the embedded default drive."""
    _check_types(path)
    return session.dataset(path)


class Result:
    """One run, in memory: its metrics, estimates, filter record, and a way to write it."""

    def __init__(self, run: RunResult):
        self.run = run
        self._trajectories = None

    @property
    def metrics(self) -> dict:
        """The nested dict of ``metrics.json``."""
        return self.run.metrics

    @property
    def config(self) -> dict:
        """The resolved configuration (human units), as in ``config.resolved.yaml``."""
        return self.run.cfg

    @property
    def series(self) -> dict[str, PoseSeries]:
        """The estimates and the ground truth as fusion-eval pose series."""
        return self.run.series

    @property
    def filter(self):
        """The filter's record (biases, sigmas, the covariance of position and attitude, NIS)."""
        return self.run.filt

    @property
    def trajectories(self) -> dict:
        """evo ``PoseTrajectory3D`` of ``fused``, ``lidar``, ``gnss``, ``imu_only`` and ``groundtruth``."""
        if self._trajectories is None:
            from .evaluation.trajectory import to_evo

            self._trajectories = {k: to_evo(s, k) for k, s in self.run.series.items()}
        return self._trajectories

    def write(self, out_dir: str | Path, overwrite: bool = False) -> Path:
        """Write every output of ``fusion-eval run --out out_dir`` (atomically: all or nothing)."""
        from . import report

        with StagedDir(Path(out_dir), overwrite=overwrite) as out:
            report.write_run(out, self.run)
        return Path(out_dir)

    def __repr__(self) -> str:
        ape = self.metrics["estimates"].get("fused", {}).get("ape", {}).get("translation_m", {})
        return f"<fusion_eval.Result {self.run.dataset}: fused APE RMSE {ape.get('rmse', float('nan')):.3f} m>"


def run(dataset: Dataset | str | Path | None = None, overrides: dict | None = None, config: str | Path | dict | None = None,
        variant: str | Path | None = None, progress: Callable[[float], None] | None = None,
        jobs: int | None = None, trials: int = 1) -> Result:
    """Run a dataset through the configured filter and evaluate it, in memory (nothing is written).

    Layers as for ``fusion-eval run``: the defaults < the manifest's suggestions < ``config`` (a file or a
    ``{section: {key: value}}`` dict) < ``variant`` (a name in ``configs/variants`` or a file) < ``overrides``.
    ``trials`` > 1: Monte-Carlo trials over the seeds (``metrics["trials"]``; the result is trial 0's).
    """
    from .variants import resolve_variant

    _check_types(dataset, overrides, config, progress)
    vpath = None if variant is None else resolve_variant(str(variant))
    req = session.request(config=config, variant=vpath, overrides=overrides)
    ds = dataset if isinstance(dataset, Dataset) else session.dataset(dataset)
    cfg = session.resolve(req, ds)
    return Result(execute(ds, cfg, config_source=req.source, progress=progress, jobs=jobs, trials=trials))


def _as_series(x, times: str | Path | None, what: str, fmt: str = "auto") -> tuple:
    """A pose series or an evo trajectory, its name, and where it came from."""
    from .datasets.trajectory_file import read_trajectory
    from .errors import ConfigError

    if isinstance(x, PoseSeries):
        return x, x.source, {"stamps": "given"}
    if isinstance(x, (str, Path)):
        f = read_trajectory(Path(x), times, fmt)
        return f.traj, Path(x).stem, {"file": str(x), "format": f.format, "stamps": f.stamps}
    if hasattr(x, "positions_xyz") and hasattr(x, "timestamps"):
        return x, (x.meta.get("name") or what), {"stamps": "given"}
    raise ConfigError(f"{what}: expected a PoseSeries, an evo PoseTrajectory3D or a trajectory file path, "
                      f"got {type(x).__name__}")


def evaluate(reference, estimate, alignment: str = "none", association: str = "nearest", t_max_diff_s: float = 0.01,
             rpe_delta_m: float = 100.0, segment_m: float = 100.0, segment_s: float | None = None,
             reference_times: str | Path | None = None, estimate_times: str | Path | None = None,
             engine: str = "arrays", *, fmt: str = "auto", relations: tuple[str, ...] = ("trans_part", "angle_deg"),
             up_axis: str = "auto", n_to_align: int = -1, t_offset_s: float = 0.0) -> dict:
    """evo's APE/RPE, the KITTI drift metric and the per-segment breakdown of ``estimate`` against
    ``reference`` (each a trajectory file, an evo ``PoseTrajectory3D`` or a :class:`PoseSeries`): the
    ``metrics.json`` of ``fusion-eval evaluate``, with the same options. ``engine``: ``arrays`` (evo's metrics
    on whole arrays) or ``evo`` (evo's own per-pose loops); the numbers are the same."""
    from .evaluation.estimates import evaluate_series, validate_options

    validate_options(association, alignment, t_max_diff_s, rpe_delta_m, segment_m, segment_s, engine, relations,
                     up_axis, n_to_align)
    ref, _, ref_about = _as_series(reference, reference_times, "reference", fmt)
    est, name, about = _as_series(estimate, estimate_times, "estimate", fmt)
    if name in ("groundtruth", "reference"):
        name = "estimate"
    metrics, _ = evaluate_series(ref, {name: est}, association, alignment, t_max_diff_s, rpe_delta_m, segment_m,
                                 segment_s, {name: about}, ref_stamps=ref_about["stamps"], engine=engine,
                                 relations=relations, up_axis=up_axis, n_to_align=n_to_align, t_offset_s=t_offset_s)
    return {"reference": ref_about.get("file", getattr(ref, "source", "reference")), "reference_stamps": ref_about["stamps"],
            **metrics}
