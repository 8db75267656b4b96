"""Runs that may share one data preparation: a sweep's batches and a tune's trials on one worker."""

from __future__ import annotations

import hashlib
import json

from .config import keys_read_by

# Keys that only the filter reads (declared with ``reads="filter"`` beside their default, in the module of the
# formulation or observation that reads them): not the data preparation, not the evaluation. Runs of one dataset
# whose configurations differ only in these are one batch: the data is loaded and prepared once, the unfiltered
# estimates evaluated once, and each run replays and evaluates its own filter.
FILTER_ONLY_KEYS = keys_read_by("filter")


def batch_key(dataset: str, cfg: dict) -> str:
    """Equal for two runs that may share one preparation: same dataset, same configuration but for the
    values of :data:`FILTER_ONLY_KEYS` (an 'auto' value stays distinct: preparation estimates it)."""
    masked = {sect: dict(body) for sect, body in cfg.items()}
    for k in FILTER_ONLY_KEYS:
        sect, key = k.split(".", 1)
        if key in masked.get(sect, {}):
            masked[sect][key] = "auto" if masked[sect][key] == "auto" else "<filter>"
    return hashlib.sha256(json.dumps({"dataset": dataset, "config": masked}, sort_keys=True,
                                     default=str).encode()).hexdigest()[:12]
