"""The record every benchmark writes with ``--json``: the commit and date it was
measured at, then its own fields."""

import json
import subprocess
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def commit_of(checkout: Path = ROOT, mark_dirty: bool = False) -> str:
    """The short commit ``checkout`` is at (``+dirty`` after it when ``mark_dirty`` and
    tracked files are edited; ``"unknown"`` outside git): what a row was measured at."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=checkout,
                              capture_output=True, text=True, check=True).stdout.strip()
        dirty = mark_dirty and subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=checkout,
            capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def write_record(path: Path | None, **fields) -> dict:
    """``{"commit", "date", **fields}``, written as JSON to ``path`` (its folder made)
    unless ``path`` is None; returned either way."""
    record = {"commit": commit_of(), "date": time.strftime("%Y-%m-%d"), **fields}
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(record, indent=1))
    return record
