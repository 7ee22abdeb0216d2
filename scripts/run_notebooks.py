"""Execute the research notebooks and keep the executed copies (with their figures).

    .venv/bin/python scripts/run_notebooks.py [--quick] [--out out/notebooks] [--force]
        [NAME ...]

Each notebook (the jupytext source ``notebooks/NN_*.py``) runs top to bottom in a
fresh kernel of this interpreter, from the ``notebooks/`` folder; the executed
``.ipynb`` is written to ``--out`` (the committed notebooks stay output-free). A
failing cell stops with its traceback and a non-zero exit. ``--quick`` sets
``STICKSLIP_NOTEBOOK_QUICK=1`` (the reduced sizes CI uses). Full sizes take about
2 min for notebooks 1, 3, 5, 6 together, 1.5 min for 2, 10-15 min for 4 and about
half an hour for 7 on two cores.
"""

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import jupytext
import nbclient
import nbformat

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = ROOT / "notebooks"


def kernel_spec_dir() -> Path:
    """A kernelspec for this interpreter (not whatever `python3` the machine has)."""
    root = Path(tempfile.mkdtemp(prefix="stickslip-kernel-"))
    spec = root / "kernels" / "stickslip"
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "stickslip", "language": "python"}))
    return root


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("names", nargs="*", help="notebook names or numbers (default: all)")
    ap.add_argument("--quick", action="store_true", help="the reduced sizes CI uses")
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "notebooks")
    ap.add_argument("--force", action="store_true", help="replace existing executed copies")
    args = ap.parse_args()
    sources = sorted(NOTEBOOKS.glob("[0-9][0-9]_*.py"))
    if args.names:
        sources = [s for s in sources if any(s.stem.startswith(n) or s.stem == n
                                             for n in args.names)]
        if not sources:
            sys.exit(f"no notebook matches {args.names}")
    args.out.mkdir(parents=True, exist_ok=True)
    targets = [args.out / f"{s.stem}.ipynb" for s in sources]
    existing = [t for t in targets if t.exists()]
    if existing and not args.force:
        sys.exit(f"{existing[0]} exists; pass --force to replace it")
    if args.quick:
        os.environ["STICKSLIP_NOTEBOOK_QUICK"] = "1"
    else:
        os.environ.pop("STICKSLIP_NOTEBOOK_QUICK", None)
    os.environ["MPLBACKEND"] = "module://matplotlib_inline.backend_inline"
    os.environ["JUPYTER_PATH"] = str(kernel_spec_dir())
    for src, target in zip(sources, targets, strict=True):
        nb = jupytext.read(src)
        t0 = time.perf_counter()
        print(f"{src.name} ...", flush=True)
        try:
            nbclient.NotebookClient(nb, timeout=3600, kernel_name="stickslip",
                                    resources={"metadata": {"path": str(NOTEBOOKS)}}).execute()
        except nbclient.exceptions.CellExecutionError as err:
            print(err, file=sys.stderr)
            return 1
        tmp = target.with_suffix(".ipynb.tmp")
        nbformat.write(nb, tmp)
        tmp.replace(target)
        print(f"  {time.perf_counter() - t0:.0f} s -> {target}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
