"""One fresh Python process of this virtual environment running a checkout's code, for
the experiments that compare two checkouts side by side."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path


def run_in_checkout(checkout: Path, code: str, args: Sequence[str], **env: str) -> dict:
    """Run ``code`` (``python -c``) with ``args`` in a fresh process whose ``PYTHONPATH``
    is ``checkout`` (its working folder too; ``env`` added to a bare environment),
    and return the JSON object it prints last. That object's ``module`` (the
    ``stickslip_jax.__file__`` it imported) must lie in the checkout: a RuntimeError
    otherwise."""
    base = {"PYTHONPATH": str(checkout.resolve()), "PATH": "/usr/bin:/bin",
            "MPLBACKEND": "Agg"}
    done = subprocess.run([sys.executable, "-c", code, *map(str, args)],
                          env={**base, **env}, cwd=checkout, capture_output=True, text=True,
                          check=True)
    row = json.loads(done.stdout.strip().splitlines()[-1])
    if not row["module"].startswith(str(checkout.resolve())):
        raise RuntimeError(f"{checkout} ran {row['module']}")
    return row
