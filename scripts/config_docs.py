#!/usr/bin/env python3
"""Rewrite the README's configuration table and configs/default.yaml from the schema (each key's S(...) declaration).

    python scripts/config_docs.py          # rewrite both; prints the files that changed
    python scripts/config_docs.py --check  # exit 1 if either is out of date (what tests/test_config.py checks)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from fusion_eval import config_docs  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="only say whether the files are current")
    args = ap.parse_args()
    if args.check:
        stale = [str(p.relative_to(ROOT)) for p in config_docs.stale(ROOT)]
        print("out of date: " + ", ".join(stale) if stale else "current")
        return 1 if stale else 0
    changed = config_docs.write(ROOT)
    print("rewrote " + ", ".join(changed) if changed else "already current")
    return 0


if __name__ == "__main__":
    sys.exit(main())
