"""``fusion-eval simulate``: a synthetic drive with known truth (the simulator is :mod:`fusion_eval.simulate`)."""

from __future__ import annotations

from pathlib import Path


def simulate(out_dir: Path, profile: str, duration_s: float, seed: int, grade: str, sets: tuple[str, ...] = (),
             overwrite: bool = False) -> dict:
    from ..simulate.dataset import simulate as run_sim

    return run_sim(out_dir, profile, duration_s, seed, grade, tuple(sets), overwrite=overwrite)
