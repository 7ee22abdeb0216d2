"""benchmarks/experiments/replay_first_refits.py: round one's first refits rebuilt from a recorded
row follow :func:`stickslip_jax.diagnose.rules.first_refits` under either policy."""

import dataclasses
import importlib.util
from pathlib import Path

from stickslip_jax.diagnose import Policy

SCRIPT = (Path(__file__).resolve().parents[1] / "benchmarks" / "experiments"
          / "replay_first_refits.py")


def _script():
    spec = importlib.util.spec_from_file_location("replay_first_refits", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _entry(name, score, held, free, status="refitted", rss_before=None):
    return {"name": name, "score_statistic": score, "sizing_drop": held,
            "sizing_drop_baseline_free": free, "sizing_baseline_free_converged": True,
            "sizing_baseline_free_move": 0.2, "status": status, "rss_before": rss_before,
            "refitted": status == "refitted", "criterion_delta": -1e4,
            "explained_share_of_excess": 0.9}


def test_a_recorded_round_is_replayed_under_the_default_and_another_policy():
    replay = _script()
    # N = 20 000 samples at χ² 2: an excess of 20 000; the leader's sizing removes 60 %
    # of it, a competitor's 30 % of the leader's rank, a third 10 %.
    row = {"set": "x", "named": ["creep"], "chi2_before": 2.0, "candidates_by_round": [[
        _entry("creep", 12_000, 11_000, 12_000, rss_before=40_000),
        _entry("sensor_drift", 3_600, 3_000, 3_600, status="not refitted"),
        _entry("stribeck", 1_200, 1_000, 1_200, status="not refitted"),
        _entry("external_load", 5.0, 0.0, None, status="scored")]]}
    sized = replay.sized_entries(row["candidates_by_round"][0])
    assert [r.name for r in sized] == ["creep", "sensor_drift", "stribeck"]
    excess, n_obs = replay.round_one_excess(row)
    assert (excess, n_obs) == (20_000.0, 20_000.0)
    default, wider = replay.replay(
        row, dataclasses.replace(Policy(), competitive_share=0.05), top=3)
    # The default's quarter of the leader keeps sensor_drift (30 %), not stribeck (10 %).
    assert default == ["creep", "sensor_drift"]
    assert wider == ["creep", "sensor_drift", "stribeck"]
    # A leader that removes nearly the whole excess is refitted alone.
    row["candidates_by_round"][0][0].update(sizing_drop=19_000, score_statistic=19_500)
    alone, _ = replay.replay(row, Policy(), top=3)
    assert alone == ["creep"]
    # Rows without records (before ec4632c) are skipped.
    assert replay.replay({"set": "old", "named": []}, Policy(), top=3) is None


def test_a_held_sizing_above_the_baseline_defers_an_entry_only_where_it_converged():
    replay = _script()
    row = {"set": "y", "named": ["sensor_delay"], "chi2_before": 1.1,
           "candidates_by_round": [[
               _entry("sensor_delay", 2_600, 2_400, 2_600, rss_before=30_000),
               _entry("drive_bandwidth", 440, -8e5, 2_500, status="not refitted")]]}
    # Recorded before the held sizing's convergence was: read as converged, the rule as
    # it was; as stopped at the step cap, its rank value (its free drop) judges it.
    assert replay.replay(row, Policy(), top=3)[0] == ["sensor_delay"]
    assert replay.replay(row, Policy(), top=3, unrecorded_converged=False)[0] == [
        "sensor_delay", "drive_bandwidth"]
    row["candidates_by_round"][0][1]["sizing_converged"] = False
    assert replay.replay(row, Policy(), top=3)[0] == ["sensor_delay", "drive_bandwidth"]
