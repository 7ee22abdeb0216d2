"""The diagnosis's work budget: counted work, what it allows, that no clock decides,
and the CLI that exposes it."""

import time

import pytest

from stickslip_jax.diagnose import budget as budget_mod
from stickslip_jax.diagnose.budget import (
    CLOSED_FORM_STAGE_FACTOR,
    DEFAULT_WORK_BUDGET,
    REFERENCE_SUBSTEPS,
    SOLVED_STAGE_FACTOR,
    STAGE_STEP_WEIGHT,
    TANGENT_WEIGHT,
    UNIT,
    Budget,
    evaluation_work,
    fit_work,
    plan_factor,
)

PROTOCOL_SAMPLES = 17 * 2500
"""The paper's 17-recording protocol on its padded grid (17 recordings, the longest
2500 samples at 25 kHz)."""
BASELINE_COLUMNS = 42
"""The baseline's θ on it: Mp, Dp, Kp, Ds, rho0, 35 PI weights, z_ba per direction."""


def test_work_is_counted_from_samples_columns_steps_and_the_plan():
    assert evaluation_work(1000, 0) == 1000.0
    assert evaluation_work(1000, 10) == pytest.approx(1000 * (1 + 10 * TANGENT_WEIGHT))
    assert evaluation_work(1000, 10, 3.5) == pytest.approx(3.5 * evaluation_work(1000, 10))
    # A fit of s steps evaluates the start and then a point per step, each by a value
    # pass first and with its Jacobian when accepted (the most: every point).
    one = evaluation_work(1000, 3) + evaluation_work(1000, 0)
    assert fit_work(1000, 3, 25) == pytest.approx(26 * one)
    assert fit_work(1000, 3, 0) == pytest.approx(one)


def test_a_fit_is_charged_the_evaluations_it_made():
    from types import SimpleNamespace

    from stickslip_jax.diagnose.budget import solve_work

    # 21 steps, 5 rejected: 17 Jacobians (start and accepted points), 22 value passes.
    done = SimpleNamespace(jacobians=17, values=22, iterations=21)
    assert solve_work(1000, 42, done, 2.0) == pytest.approx(
        17 * evaluation_work(1000, 42, 2.0) + 22 * evaluation_work(1000, 0, 2.0))
    assert solve_work(1000, 42, done) < fit_work(1000, 42, done.iterations)


def test_an_identification_is_charged_each_stretch_at_the_plan_it_ran_at():
    """A step that starts at a fast model and re-plans is charged its first stretch at
    the start's sub-steps and the rest at the re-planned ones, not all at the start's;
    the final simulation and its step-doubling estimate at the final plan."""
    from types import SimpleNamespace

    import numpy as np

    from stickslip_jax.diagnose.problem import identification_work
    from stickslip_jax.identify.steps import PlanSegment
    from stickslip_jax.model.stages import IdentityInput
    from stickslip_jax.stepping import StepPlan

    recordings = [SimpleNamespace(name=n, time_s=np.zeros(k))
                  for n, k in (("step", 500), ("saw", 2000), ("sine", 1500))]
    data = SimpleNamespace(recordings=recordings, mask=np.ones((3, 2000)))
    fast, slow = StepPlan(4 * REFERENCE_SUBSTEPS), StepPlan(REFERENCE_SUBSTEPS)
    dynamics = SimpleNamespace(recordings=["step"], result=SimpleNamespace(theta=np.zeros(3)),
                               segments=[PlanSegment(fast, 11, 14)])
    joint = SimpleNamespace(recordings=["step", "saw", "sine"],
                            result=SimpleNamespace(theta=np.zeros(42)),
                            segments=[PlanSegment(fast, 3, 4), PlanSegment(slow, 20, 26)])
    skipped = SimpleNamespace(recordings=[], result=None, segments=[])
    ident = SimpleNamespace(steps=[dynamics, skipped, joint], plan=slow, uncertainty=object())

    def factor(plan):
        return plan_factor(plan, IdentityInput())

    work = identification_work(ident, data, factor)
    expected = (11 * evaluation_work(500, 3, 4.0) + 14 * evaluation_work(500, 0, 4.0)
                + 3 * evaluation_work(6000, 42, 4.0) + 4 * evaluation_work(6000, 0, 4.0)
                + 20 * evaluation_work(6000, 42) + 26 * evaluation_work(6000, 0)
                + evaluation_work(6000, 42) + evaluation_work(6000, 0, 2.0))
    assert work == pytest.approx(expected)
    # Charged all at the start's plan, the joint step would cost almost 4x as much.
    all_fast = (11 * evaluation_work(500, 3, 4.0) + 14 * evaluation_work(500, 0, 4.0)
                + 23 * evaluation_work(6000, 42, 4.0) + 30 * evaluation_work(6000, 0, 4.0))
    assert work < 0.4 * all_fast
    # Without an uncertainty the final simulation carries no Jacobian; without a final
    # simulation nothing is charged for it.
    ident.uncertainty = None
    assert identification_work(ident, data, factor) == pytest.approx(
        expected - evaluation_work(6000, 42) + evaluation_work(6000, 0))
    ident.plan = None
    assert identification_work(ident, data, factor) == pytest.approx(
        expected - evaluation_work(6000, 42) - evaluation_work(6000, 0, 2.0))


def test_the_plan_factor_counts_sub_steps_and_what_a_drive_stage_adds():
    from stickslip_jax.model.extensions import (
        ClippedSlewInput,
        LowPassInput,
        ParallelInputs,
        SlewLimitedInput,
    )
    from stickslip_jax.model.stages import IdentityInput
    from stickslip_jax.stepping import StepPlan

    none, low_pass = IdentityInput(), LowPassInput(1e-6)
    slew = ClippedSlewInput(1e6, 1e-6)             # by RK4 steps of its rate
    assert plan_factor(StepPlan(REFERENCE_SUBSTEPS), none) == 1.0
    # Sub-steps cost in proportion: a mode 4x faster than the baseline's, 4x the work.
    assert plan_factor(StepPlan(4 * REFERENCE_SUBSTEPS), none) == pytest.approx(4.0)
    # A closed-form stage costs the same whatever its time constant...
    assert plan_factor(StepPlan(REFERENCE_SUBSTEPS), low_pass) == CLOSED_FORM_STAGE_FACTOR
    # ...a stage integrated apart by its own steps, per step (a fast slew limit: 40).
    assert plan_factor(StepPlan(REFERENCE_SUBSTEPS, stage_substeps=5), slew) == \
        pytest.approx(1 + 5 * STAGE_STEP_WEIGHT)
    assert plan_factor(StepPlan(2 * REFERENCE_SUBSTEPS, stage_substeps=40), slew) == \
        pytest.approx(2 * (1 + 40 * STAGE_STEP_WEIGHT))
    # The tanh slew limit's exact step costs its Newton steps, whatever its τ; beside a
    # low-pass (the drive probe) as much.
    for stage in (SlewLimitedInput(1e6, 1e-6), SlewLimitedInput(1e6, 1e-9),
                  ParallelInputs((LowPassInput(5e-6, 0.0), SlewLimitedInput(1e6, 5e-6, 0.0)))):
        assert plan_factor(StepPlan(REFERENCE_SUBSTEPS), stage) == SOLVED_STAGE_FACTOR


def test_the_reference_plan_is_the_default_profiles_on_the_protocol():
    """The unit's reference sub-steps are what the default stepping plans for the default
    profile at the paper's protocol; a stage stepped by RK4 with a sub-µs time constant
    plans many stage steps, the tanh slew limit (exact step) none."""
    import equinox as eqx

    import stickslip_jax as ss
    from stickslip_jax.model.extensions import ClippedSlewInput, SlewLimitedInput
    from stickslip_jax.synthetic import paper_protocol

    dt = paper_protocol()[0].recording().dt
    act = ss.lu2015_slc1720()
    assert ss.plan_steps(act, dt).substeps == REFERENCE_SUBSTEPS
    fast = eqx.tree_at(lambda a: a.input_stage, act, ClippedSlewInput(1e6, 0.1e-6))
    plan = ss.plan_steps(fast, dt)
    assert plan_factor(plan, fast.input_stage) > 10.0
    exact = eqx.tree_at(lambda a: a.input_stage, act, SlewLimitedInput(1e6, 0.1e-6))
    plan = ss.plan_steps(exact, dt)
    assert plan.substeps == REFERENCE_SUBSTEPS and plan.stage_substeps == 1
    assert plan_factor(plan, exact.input_stage) == SOLVED_STAGE_FACTOR


def test_the_default_is_about_what_540_s_allowed_on_the_protocol():
    """540 s on a quiet 2-core CPU: about 1.15 s per baseline-sized Jacobian evaluation
    of the 17 recordings (module docstring), so 400-550 of them."""
    one = evaluation_work(PROTOCOL_SAMPLES, BASELINE_COLUMNS)
    assert 400 <= DEFAULT_WORK_BUDGET / one <= 550
    # The most a 25-step refit of the baseline with a 1-parameter entry can cost: ~7 %
    # of the default (every point tried accepted, each a value pass and a Jacobian), so
    # at least 14 such refits fit in it; fewer at a finer plan (plan_factor).
    refit = fit_work(PROTOCOL_SAMPLES, BASELINE_COLUMNS + 1, 25)
    assert 12 <= DEFAULT_WORK_BUDGET / refit <= 25


def test_the_budget_allows_work_that_ends_within_it():
    b = Budget(100.0)
    b.charge(40.0)
    assert b.spent == 40.0
    assert b.allows(60.0)
    assert not b.allows(60.5)
    assert b.allows(30.0, reserve=30.0)
    assert not b.allows(30.0, reserve=31.0)


@pytest.mark.parametrize("total", [None, 0.0, -5.0])
def test_no_budget_allows_everything(total):
    b = Budget(total)
    b.charge(1e30)
    assert b.total is None and b.allows(1e30, reserve=1e30)
    assert "no work budget" in b.progress()


def test_a_skip_is_recorded_with_its_reason():
    b = Budget(1e8)
    b.charge(9.5e7)
    note = b.skip("refit stribeck", 1.2e7)
    assert b.skipped == ["refit stribeck"]
    assert note == (f"skipped: its 1.2e+07 {UNIT} would pass the work budget of 1e+08 "
                    f"(9.5e+07 spent)")
    assert b.record() == {"unit": UNIT, "total": 1e8, "spent": 9.5e7,
                          "baseline_spent": 0.0, "skipped": ["refit stribeck"]}


def test_refuse_records_a_skip_only_when_the_work_does_not_fit():
    b = Budget(100.0)
    b.charge(40.0)
    assert b.refuse("refit creep", 50.0, reserve=10.0) is None
    assert b.skipped == []
    note = b.refuse("refit creep", 50.0, reserve=10.5)
    assert note.startswith("skipped: its 50 ") and b.skipped == ["refit creep"]


def test_notes_join_in_order_and_skip_empty_ones():
    from stickslip_jax.diagnose.results import CandidateResult

    res = CandidateResult.__new__(CandidateResult)
    res.note = ""
    res.add_note("a")
    res.add_note("b")
    res.add_note("first", first=True)
    res.add_note("")
    assert res.note == "first; a; b"


def test_the_baselines_work_is_its_own_and_never_skips_a_refit():
    """A bent identification that spends ten budgets leaves the refits all of theirs
    (#63: a drive low-pass's identification spent 1.47e8 of 1e8, and the drive stage's
    entry was skipped)."""
    b = Budget(1e8)
    with b.baseline():
        b.charge(1.0e9)
    b.charge(4e7)
    assert (b.baseline_spent, b.spent) == (1.0e9, 4e7)
    assert b.allows(6e7) and not b.allows(6.1e7)
    assert b.record()["baseline_spent"] == 1.0e9
    assert "beside the baseline's 1e+09" in b.progress()


def _scripted_run(budget: Budget) -> list[str]:
    """A diagnosis's budget calls, scripted: core work charged, then optional refits
    (a drive-stage entry among them) asked for with the learned correction's reserve;
    a refit that runs is charged at the steps it took. Returns the decisions."""
    n, k = PROTOCOL_SAMPLES, BASELINE_COLUMNS
    with budget.baseline():  # its own account
        budget.charge(fit_work(n, k, 99))  # identification from the profile, about
        budget.charge(fit_work(n, k, 75))  # baseline polish
    budget.charge(evaluation_work(n, k + 20))  # scores
    for _ in range(5):  # sizings: 1-3 parameters, 15 steps
        budget.charge(fit_work(n, 2, 15))
    reserve = 2 * fit_work(n, k + 6, 25)
    decisions = []
    for name, drive, steps_taken in [("creep", False, 25), ("stribeck", False, 11),
                                     ("drive_bandwidth", True, 25), ("external_load", False, 25),
                                     ("structural_mode", False, 25), ("sensor_delay", False, 25),
                                     ("contact_damping", False, 25)]:
        factor = 1 + 5 * STAGE_STEP_WEIGHT if drive else 1.0  # a 1 µs slew limit
        need = fit_work(n, k + 1, 25, factor)
        if budget.allows(need, reserve):
            budget.charge(fit_work(n, k + 1, steps_taken, factor))
            decisions.append(f"refit {name}")
            time.sleep(0)  # where the real run spends its seconds
        else:
            budget.skip(f"refit {name}", need)
            decisions.append(f"skip {name}")
        budget.progress()  # the display reads the clock; nothing else may
    return decisions


def test_the_decisions_do_not_depend_on_the_clock(monkeypatch):
    """The same work, on a machine 100x faster, 100x slower, or one whose clock jumps
    (a busy machine): identical decisions and records. Only the ETA differs."""
    real = time.perf_counter

    def run(rate: float, jumps: bool = False):
        t0 = real()
        calls = [0]

        def clock():
            calls[0] += 1
            return t0 + rate * (real() - t0) + (1e4 * calls[0] if jumps else 0.0)
        monkeypatch.setattr(time, "perf_counter", clock)
        monkeypatch.setattr(budget_mod.time, "perf_counter", clock)
        b = Budget(DEFAULT_WORK_BUDGET / 2)
        decisions = _scripted_run(b)
        record = b.record()
        return decisions, record

    quick, slow, busy = run(0.01), run(100.0), run(1.0, jumps=True)
    assert quick == slow == busy
    decisions, record = quick
    # The budget bites part-way: some refits ran, the later ones were skipped.
    assert "refit creep" in decisions and "skip contact_damping" in decisions
    assert record["skipped"] == [d.replace("skip ", "refit ") for d in decisions
                                 if d.startswith("skip")]


def test_the_progress_line_gives_an_eta_from_the_clock_only():
    now = [100.0]
    b = Budget(1e8, clock=lambda: now[0])
    b.charge(2.5e7)
    now[0] = 130.0  # 30 s for a quarter of the budget
    line = b.progress()
    assert "25 % of the work budget" in line and "about 90 s" in line


def test_the_cli_takes_a_multiple_of_the_default_and_refuses_seconds(tmp_path):
    import inspect

    from typer.testing import CliRunner

    from stickslip_jax.cli.diagnose_cmd import diagnose_command
    from stickslip_jax.cli.main import app

    option = inspect.signature(diagnose_command).parameters["work_budget"].default
    assert option.default == 1.0
    runner = CliRunner()
    res = runner.invoke(app, ["diagnose", str(tmp_path), "--out", str(tmp_path / "o"),
                              "--time-budget", "540"])
    assert res.exit_code == 2
    assert "--time-budget is replaced by --work-budget" in res.output
    res = runner.invoke(app, ["diagnose", str(tmp_path), "--out", str(tmp_path / "o"),
                              "--work-budget", "-1"])
    assert res.exit_code == 2 and "--work-budget must be 0" in res.output


def test_the_learned_correction_reserve_covers_its_three_fits():
    """The reserve kept for the learned correction is the work of its three fits at
    max_steps: the refit's held stage (the PI weights held), its full stage, and the
    fit of the kept features (at most as many columns)."""
    import numpy as np

    import stickslip_jax as ss
    from stickslip_jax.diagnose.config import DEFAULT_CONFIG
    from stickslip_jax.diagnose.problem import Problem
    from stickslip_jax.diagnose.refit import RefitSetup
    from stickslip_jax.identify.dataset import Dataset
    from stickslip_jax.model.extensions import LEARNED_FEATURES
    from stickslip_jax.synthetic import paper_protocol, simulate_set

    act = ss.lu2015_slc1720()
    specs = paper_protocol(periods=2, amplitudes=(60.0,), frequencies=(500.0,),
                           step_duration_s=0.01, sine_periods=1)[:2]
    data = Dataset.from_recordings(simulate_set(act, specs, noise_m=1e-9, seed=1))
    problem = Problem(data, np.full(len(data), 1e-9), {}, None)
    setup = RefitSetup(problem, [], BASELINE_COLUMNS, 25, DEFAULT_CONFIG.identify_max_steps,
                       DEFAULT_CONFIG.carry_on_steps)
    n, k = problem.samples, BASELINE_COLUMNS + len(LEARNED_FEATURES)
    held = np.size(act.hysteresis.weights)
    factor = problem.plan_factor(act)
    want = fit_work(n, k - held, 25, factor) + 2 * fit_work(n, k, 25, factor)
    assert setup.learned_reserve(act) == pytest.approx(want, rel=1e-12)
    assert want > 2 * fit_work(n, k, 25, factor)  # the held stage counts
