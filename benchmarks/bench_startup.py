"""What starting a command costs before it does anything: importing the command line.

    .venv/bin/python benchmarks/bench_startup.py --json benchmarks/results/startup.json
    .venv/bin/python benchmarks/bench_startup.py --against /path/to/other/checkout
    .venv/bin/python benchmarks/bench_startup.py --against-pythonpath /tmp/other_deps

Each run is a fresh process (``python -c "import stickslip_jax.cli.main"``, the working
directory the checkout measured, so that its package is the one imported); the median
and range over ``--repeats`` runs. With ``--against DIR`` another checkout (a worktree
of an earlier commit) is timed the same way, its runs interleaved with these, and the
ratio printed: the machine's load then weighs on both alike. With
``--against-pythonpath DIR`` the other arm is this checkout with ``DIR`` first on
``PYTHONPATH``: other versions of dependencies, installed there with ``pip install
--no-deps --target DIR``. One run more with
``python -X importtime`` lists the modules whose import took longest (cumulative) and
says whether the optional heavy ones (:data:`OPTIONAL`, imported where a command needs
them) were imported at start.
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from results_record import commit_of, write_record

ROOT = Path(__file__).resolve().parent.parent
OPTIONAL = ("scipy.stats", "scipy.signal", "optimistix", "matplotlib")
"""Modules a command imports only when it needs them (the diagnosis's χ² tail, the
z_ba surface's solver, the figures)."""
IMPORT = "import stickslip_jax.cli.main"


def environment(pythonpath: Path | None) -> dict[str, str] | None:
    """This environment with ``pythonpath`` first on ``PYTHONPATH`` (None: unchanged)."""
    if pythonpath is None:
        return None
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(pythonpath), env.get("PYTHONPATH"))
                                        if p)
    return env


def import_seconds(checkout: Path, pythonpath: Path | None = None) -> float:
    """Wall time of one fresh process importing the command line of ``checkout`` [s]."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", IMPORT], cwd=checkout, check=True,
                   env=environment(pythonpath))
    return time.perf_counter() - t0


def import_profile(checkout: Path, top: int, pythonpath: Path | None = None
                   ) -> tuple[list[tuple[str, float]], list[str]]:
    """The ``top`` slowest imports (cumulative [s]) and the :data:`OPTIONAL` modules
    imported, from ``-X importtime`` (one run)."""
    code = (f"{IMPORT}; import json, sys; "
            f"print(json.dumps([m for m in {list(OPTIONAL)!r} if m in sys.modules]))")
    out = subprocess.run([sys.executable, "-X", "importtime", "-c", code], cwd=checkout,
                         capture_output=True, text=True, check=True,
                         env=environment(pythonpath))
    rows = []
    for line in out.stderr.splitlines():
        parts = line.split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            rows.append((parts[2].strip(), int(parts[1]) / 1e6))
    rows.sort(key=lambda r: -r[1])
    return rows[:top], json.loads(out.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--against", type=Path, default=None,
                    help="another checkout to time beside this one (interleaved)")
    ap.add_argument("--against-pythonpath", type=Path, default=None,
                    help="time this checkout with DIR first on PYTHONPATH beside it")
    ap.add_argument("--top", type=int, default=12)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    if args.against and args.against_pythonpath:
        ap.error("--against and --against-pythonpath: give one")
    arms = {"this": (ROOT, None)}
    if args.against:
        arms["against"] = (args.against.resolve(), None)
    elif args.against_pythonpath:
        arms["against"] = (ROOT, args.against_pythonpath.resolve())
    for path, extra in arms.values():
        import_seconds(path, extra)  # warm the file cache and the bytecode
    times: dict[str, list[float]] = {name: [] for name in arms}
    for _ in range(args.repeats):
        for name, (path, extra) in arms.items():
            times[name].append(import_seconds(path, extra))
    result: dict = {"import": IMPORT, "repeats": args.repeats, "arms": {}}
    for name, (path, extra) in arms.items():
        slowest, optional = import_profile(path, args.top, extra)
        med = statistics.median(times[name])
        result["arms"][name] = {"checkout": str(path), "commit": commit_of(path),
                                "pythonpath_first": str(extra) if extra else None,
                                "median_s": med,
                                "min_s": min(times[name]), "max_s": max(times[name]),
                                "optional_imported": optional,
                                "slowest_imports_s": slowest}
        where = f"{path}, PYTHONPATH {extra} first" if extra else f"{path}"
        print(f"{name} ({where}): median {med:.2f} s ({min(times[name]):.2f}-"
              f"{max(times[name]):.2f}); optional modules imported: {optional or 'none'}")
        for module, seconds in slowest:
            print(f"    {seconds:6.3f} s  {module}")
    if "against" in arms:
        ratio = result["arms"]["this"]["median_s"] / result["arms"]["against"]["median_s"]
        result["this_over_against"] = ratio
        print(f"this / against: {ratio:.2f}")
    write_record(args.json, **result)


if __name__ == "__main__":
    main()
