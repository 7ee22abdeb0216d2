"""The record every benchmark writes with ``--json``: the commit and date it was
measured at, then its own fields."""

import json
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def write_record(path: Path | None, **fields) -> dict:
    """``{"commit", "date", **fields}``, written as JSON to ``path`` (its folder made)
    unless ``path`` is None; returned either way."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    record = {"commit": commit, "date": time.strftime("%Y-%m-%d"), **fields}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(record, indent=1))
    return record
