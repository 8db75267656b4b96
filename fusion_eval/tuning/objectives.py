"""What a tune minimises, named on the command line.

- ``nll``: the innovations' negative log-likelihood per update (``innovations.nll_per_update``): the likelihood of
  the data under the filter's noise settings, in its prediction-error form. Needs no ground truth; the principled
  choice for noise tuning (maximum likelihood), on the user's own robot as on KITTI.
- ``nis``: NIS calibration (``innovations.nis_calibration``): each observation's mean NIS against its dof and the
  fraction inside the 95 % interval. No ground truth either; weaker (many settings are consistent), but it checks
  what a reviewer checks.
- any metric key of ``metrics.json`` as ``check`` names them (``fused.ape.rmse``, ``fused.rpe_100m.rmse``,
  ``fused.kitti_drift.t_err_pct``, ``smoothed.ape.rmse``, ...): needs ground truth;
- a weighted sum of those: ``0.5*fused.ape.rmse+0.5*fused.rpe_100m.rmse``.

Every objective is minimised; over several drives (or Monte-Carlo seeds) its value is the mean over them.
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass

from ..errors import ConfigError
from ..evaluation import keys

ALIASES = {"nll": "innovations.nll_per_update", "nis": "innovations.nis_calibration"}
NO_TRUTH = frozenset(ALIASES.values())
_TERM = re.compile(r"^\s*(?:([0-9.eE+-]+)\s*\*\s*)?([A-Za-z_][\w.]*)\s*$")


@dataclass(frozen=True)
class Objective:
    name: str                              # as given
    terms: tuple[tuple[float, str], ...]   # (weight, flattened metric key)

    @property
    def needs_truth(self) -> bool:
        return any(k not in NO_TRUTH for _, k in self.terms)

    @property
    def is_error(self) -> bool:
        """A positive sum of metrics against the ground truth: zero is no error, so a gain can be read as a share of
        the figure (not so the innovations' nll, whose zero is arbitrary)."""
        return all(k not in NO_TRUTH and w > 0 for w, k in self.terms)

    def value(self, flat: dict) -> float:
        """The objective of one run's flattened metrics (:func:`keys.flatten`); NaN where a key is missing."""
        total = 0.0
        for w, k in self.terms:
            v = flat.get(k)
            if v is None or not math.isfinite(v):
                return math.nan
            total += w * v
        return total

    def check(self, flat: dict, where: str) -> None:
        """Refuse a key that the run's metrics do not have, naming close ones."""
        for _, k in self.terms:
            if k not in flat:
                close = difflib.get_close_matches(k, list(flat), n=3)
                truth = any(key.startswith("fused.ape.") for key in flat)
                hint = (" (the innovations' likelihood needs ln det S from the compiled replay, which a filter stepped from "
                        "Python does not record: an iterated update, filter.iterations > 1, or the odometer + gyro model; "
                        "use the nis objective, or a metric with ground truth)" if k == "innovations.nll_per_update" else
                        f" (did you mean {', '.join(close)}?)" if close else
                        " (ground-truth metrics need a dataset with ground truth)" if k not in NO_TRUTH and not truth else
                        " (e.g. nll, nis, fused.ape.rmse, fused.rpe_100m.rmse, fused.kitti_drift.t_err_pct; "
                        "`fusion-eval check --help` names the keys)")
                raise ConfigError(f"objective {self.name!r}: {where} has no metric {k!r}{hint}")


def parse(text: str) -> Objective:
    terms = []
    for part in text.split("+"):
        m = _TERM.match(part)
        if not m:
            raise ConfigError(f"objective {text!r}: expected nll, nis, a metric key or a weighted sum such as "
                              "0.5*fused.ape.rmse+0.5*fused.rpe_100m.rmse")
        w = float(m.group(1)) if m.group(1) else 1.0
        if not (math.isfinite(w) and w > 0):
            raise ConfigError(f"objective {text!r}: weights must be positive numbers, got {m.group(1)}")
        key = ALIASES.get(m.group(2), m.group(2))
        why = keys.not_an_error(key)
        if why:             # minimised, a NEES share inside its interval chose the least consistent setting
            raise ConfigError(f"objective {text!r}: {key} is {why}")
        terms.append((w, key))
    return Objective(text, tuple(terms))


def flatten(metrics: dict) -> dict[str, float]:
    return keys.flatten(metrics)
