"""benchmarks/bench_ablation.py refuses ``--fields`` and ``--moves`` it cannot rerun (a
field removed from Policy, one not replayed, a typo) instead of rerunning nothing for
them."""

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_ablation.py"


def _script():
    spec = importlib.util.spec_from_file_location("bench_ablation", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_unknown_fields_and_moves_are_named():
    ablation = _script()
    replayable = ["explained_min", "second_look_chi2"]
    assert ablation.unknown_names(["explained_min"], replayable, ("x0.5", "off")) == ""
    why = ablation.unknown_names(["explained_min", "gone_field"], replayable, ("x3",))
    assert "--fields: no replayable Policy field gone_field" in why
    assert "explained_min, second_look_chi2" in why  # what could have been asked
    assert "--moves: no move x3" in why
    # A field the script does not replay (it needs reruns of its own) is refused too.
    for field in ablation.NOT_REPLAYED:
        assert field in ablation.unknown_names([field], replayable, ())
