"""The diagnosis's time budget: what it allows, and the CLI default that mirrors it."""

import pytest

from stickslip_jax.diagnose.budget import (
    DEFAULT_TIME_BUDGET_S,
    DRIVE_STAGE_FACTOR,
    REFIT_GUESS_S,
    Budget,
)


def test_the_budget_allows_work_that_ends_within_it():
    b = Budget(100.0, start=0.0)
    b.elapsed = lambda: 40.0  # a run 40 s in
    assert b.allows(60.0)
    assert not b.allows(60.5)
    assert b.allows(30.0, reserve_s=30.0)
    assert not b.allows(30.0, reserve_s=31.0)


def test_refit_estimates_follow_the_refits_seen():
    b = Budget(100.0)
    assert b.refit_estimate() == REFIT_GUESS_S
    assert b.refit_estimate(drive_stage=True) == REFIT_GUESS_S * DRIVE_STAGE_FACTOR
    assert b.learned_estimate() == 2 * REFIT_GUESS_S
    # set_10 from the profile: three refits without a drive stage.
    for wall in (30.2, 44.8, 37.8):
        b.record_refit(wall, drive_stage=False)
    assert b.refit_estimate() == 44.8  # the slowest of its kind
    # An amplifier refit not timed yet: the others scaled (it took 101.9 s).
    assert b.refit_estimate(drive_stage=True) == pytest.approx(44.8 * DRIVE_STAGE_FACTOR)
    b.record_refit(101.9, drive_stage=True)
    assert b.refit_estimate(drive_stage=True) == 101.9
    assert b.refit_estimate() == 44.8
    assert b.learned_estimate() == pytest.approx(60.4)  # two of the quickest
    # Only refits with a drive stage seen (every model after an amplifier's acceptance).
    c = Budget(100.0)
    c.record_refit(108.0, drive_stage=True)
    assert c.refit_estimate() == pytest.approx(108.0 / DRIVE_STAGE_FACTOR)


@pytest.mark.parametrize("total", [None, 0.0, -5.0])
def test_no_budget_allows_everything(total):
    b = Budget(total, start=0.0)
    b.elapsed = lambda: 1e9
    assert b.total_s is None and b.allows(1e9, reserve_s=1e9)


def test_a_skip_is_recorded_with_its_reason():
    b = Budget(540.0, start=0.0)
    b.elapsed = lambda: 512.4
    note = b.skip("refit stribeck")
    assert b.skipped == ["refit stribeck"]
    assert "540 s" in note and "512 s spent" in note


def test_the_cli_default_is_the_library_default():
    import inspect

    from stickslip_jax.cli.diagnose_cmd import diagnose_command

    option = inspect.signature(diagnose_command).parameters["time_budget"].default
    assert option.default == DEFAULT_TIME_BUDGET_S
