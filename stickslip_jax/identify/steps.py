"""The paper's three identification steps plus a joint refinement (Lu 2015 §IV-B).

1. ``dynamics``: Mp, Dp, Kp, Ds, rho0 (Ms fixed; rho1 on request) from the step
   responses: time-domain residuals plus a log-PSD term, started from the measured
   first resonance.
2. ``hysteresis``: the PI weights (loop kept monotone) from the sine recordings, with
   the dynamics of step 1 in the loop.
3. ``friction``: z_ba per drive direction (and zba_ratio on request) from the
   scanning and stepping sawtooth recordings: trace shape and phase-locked
   per-period step lengths.
4. ``joint``: everything at once on every recording, on the maximum-likelihood
   residual (each sample in units of its recording's noise; no PSD or step-length
   terms, which only guide the first steps from afar), converged by the Gauss-Newton
   test (:data:`JOINT_GN_TOL`). Its Jacobian at the optimum gives the covariance
   (:mod:`.uncertainty`).

The friction law's names above are the paper's law's; any registered law takes part
through its :class:`~stickslip_jax.model.registry.LawParameter` records: ``step``
says which step fits a parameter (``on_request``: only when asked, ``also_fit``),
``direction`` marks a per-direction break-away quantity (:func:`dynamics_names`,
:func:`friction_names`, :func:`breakaway_names`).

Position data determine masses, dampings and stiffnesses only up to one common
factor, so one of them is held at a known value (by default ``Ms``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..blas_threads import one_blas_thread
from ..model.actuator import Actuator
from ..precision import require_float64
from ..stepping import StepPlan
from .dataset import Dataset
from .informative import Assessment, assess
from .initial import (
    measured_step_mode,
    pi_over_range,
    scale_pi_quasistatic,
    scale_to_step_mode,
)
from .loading_curve import LoadingCurve, loading_curve_uncertainty
from .model_check import ModelCheck, check_model
from .parameters import (
    ParameterMap,
    ParameterSpec,
    fittable_names,
    law_fittable,
    parameter_getter,
    scale_invariant_names,
)
from .regime_spread import Refit, RegimeSpread, regime_spread
from .residuals import (
    DEFAULT_W_PSD,
    TraceResiduals,
    dataset_plan,
    default_batching,
    nrmse_per_recording,
    numerical_error,
    simulate_dataset,
)
from .sampling import check_sample_rates
from .sensitivities import RecordingPrograms, StepJacobian, mask_size, perturbed_mask
from .solve import (
    LMSettings,
    SolveResult,
    SolveStatus,
    solve_least_squares,
    value_and_jacobian,
)
from .step_names import (
    breakaway_names,
    dynamics_names,
    friction_names,
    requested_names,
    without_absent_directions,
)
from .uncertainty import Uncertainty, parameter_uncertainty

STEPS = ("dynamics", "hysteresis", "friction", "joint")
JOINT_GN_TOL = 0.01
"""The joint step ends when the full Gauss-Newton step from its point is shorter than
0.1 standard error in every direction (squared: 0.01; :func:`~.solve.solve_least_squares`
``gn_tol``): the reported values are then the minimiser that the standard errors
describe, to a tenth of those errors."""
JOINT_DAMPING_UPDATE = "nielsen"
"""How the joint step changes its Levenberg-Marquardt damping after an accepted step
(:attr:`~.solve.LevenbergMarquardtSteps.DAMPING_UPDATES`): Nielsen's continuous
update, which lowers the damping after every step that met half the fall its linear
model promised. The classical one (optimistix's) lowers it only after a step that met
99 % of it, which a fit whose residual stays far above the noise (a model that lacks
an effect the data hold: the residual's own curvature, left out of the Gauss-Newton
model, keeps every step short of its promise) rarely takes: its steps stay damped and
creep (a joint step on a reaction mode 23x the noise: 60 steps unconverged at 1.2
standard errors with the classical update, 22 steps to 0.02 with Nielsen's, to the same
optimum; on fits near the noise both take the same steps). The test ends the fit, so
the update changes its path, not the point it accepts. The dynamics step, with a
direction the step response leaves flat (the piezo's mass), keeps the classical update:
Nielsen's runs further along it. The diagnosis's fits keep the classical update too:
with Nielsen's (tried at 5d65386) their 15-step sizings ended elsewhere, which
reordered near-tied entries on the frozen test split (7955ad4's run, reverted by
5ebda14 and 74f3e49; benchmarks/experiments/results/diagnose_test_split_7955ad4.json)."""
STEP_SOLVE = {
    "dynamics": LMSettings(),
    "hysteresis": LMSettings(initial_damping=1e-6),
    "friction": LMSettings(initial_damping=1e-3),
    "joint": LMSettings(gn_tol=JOINT_GN_TOL, initial_damping=1e-6,
                        damping_update=JOINT_DAMPING_UPDATE),
}
"""How each step solves (:func:`~.solve.solve_least_squares`). Madsen, Nielsen &
Tingleff (2004, §3.2) start the damping at 1e-6 of the largest diagonal of JᵀJ when
the start is believed to be close to the minimiser, at 1e-3 otherwise. The hysteresis
step is nearly linear in the PI weights (a Gauss-Newton step lands next to its
optimum from anywhere) and the joint step starts at the optimum of the three: both
start at 1e-6, nearly Gauss-Newton. On the identification fixtures that took the
joint step from 171 standard errors to 0.02 in two steps (six at 1e-3, each a
Jacobian of every recording, to a point 0.002 standard errors away) and the
hysteresis step from six steps to three. The friction step's two parameters start
from the profile's values, at 1e-3; the dynamics step starts from a rough guess, with
optimistix's default (1). Only the joint step, the estimate, ends by the
Gauss-Newton test."""


def kept_finer(plan: StepPlan, before: StepPlan | None) -> StepPlan:
    """``plan``, or ``before`` (the previous step's) when it takes at least as many
    sub-steps by the same rules. The sub-steps are planned from each step's start
    values (a start stiffer than the fit asks for one more sub-step per sample than
    the fitted model) and never decrease from one step to the next, so that the steps
    share one compiled simulation (:mod:`.sensitivities`) and none is coarser than the
    one before it. Within a step they may: :func:`_solve_step` re-plans once the fit
    has left a start that needed far more."""
    if before is not None and before.substeps >= plan.substeps and \
            dataclasses.replace(before, substeps=plan.substeps) == plan:
        return before
    return plan


@dataclass(frozen=True)
class PlanSegment:
    """A stretch of a step's solve that ran at one plan of sub-steps, and the
    evaluations it made there: what a work budget charges it at
    (:func:`~stickslip_jax.diagnose.problem.identification_work`)."""

    plan: StepPlan
    jacobians: int
    """Residual evaluations with the Jacobian [-]."""
    values: int
    """Residual evaluations alone [-]."""


@dataclass
class StepReport:
    """What one step fitted, on which recordings, and how it went."""

    name: str
    recordings: list[str]
    free: list[str]
    result: SolveResult | None
    nrmse_before: float
    nrmse_after: float
    """Mean NRMSE over the step's recordings before and after it, a fraction [-]
    (files and consoles show it in percent)."""
    note: str = ""
    segments: list[PlanSegment] = field(default_factory=list)
    """The plans the step ran at, in order (more than one where it re-planned:
    :func:`_solve_step`), with the evaluations made at each; they add up to
    ``result.jacobians`` and ``result.values``."""

    @property
    def converged(self) -> bool:
        return self.result is not None and self.result.converged


@dataclass
class Identification:
    """Result of :func:`identify`: the fitted actuator and the evidence."""

    actuator: Actuator
    steps: list[StepReport]
    data: Dataset
    nrmse: np.ndarray
    """Per recording NRMSE, a fraction [-] (``fit.json``: ``nrmse_percent``)."""
    uncertainty: Uncertainty | None
    notes: list[str] = field(default_factory=list)
    q_sim: np.ndarray | None = None
    fixed: dict[str, float] = field(default_factory=dict)
    numerical_error_m: np.ndarray | None = None
    """Per recording: how far the simulator's trace at the fit is from converged, RMS,
    offset removed [m] (step doubling; :func:`~.residuals.numerical_error`)."""
    loading_curve: LoadingCurve | None = None
    """The hysteresis as the data determine it: the initial loading curve at its knots
    with standard errors (:mod:`.loading_curve`); None without the PI weights free."""
    undetermined: Assessment | None = None
    """Set when the recordings cannot determine a parameter of the steps asked for
    (:func:`~.informative.assess`, judged before fitting): then nothing was fitted.
    A direction not recorded at all is only a note; its break-away is not fitted."""
    plan: StepPlan | None = None
    """The plan of sub-steps ``q_sim`` was simulated at (None when nothing was)."""
    model_check: ModelCheck | None = None
    """Whether the fitted model describes the recordings to within their noise
    (:mod:`.model_check`); None when nothing was fitted."""
    regime_spread: RegimeSpread | None = None
    """Each parameter's spread over leave-one-regime-out fits (:mod:`.regime_spread`):
    computed when the residual is beyond the noise (a mismatch or misspecified) and
    ``spread_if_mismatch`` was asked for."""

    @property
    def misspecified(self) -> bool:
        """The model misses more than the noise (:attr:`.ModelCheck.misspecified`)."""
        return self.model_check is not None and self.model_check.misspecified

    @property
    def unconverged_steps(self) -> list[StepReport]:
        """The steps whose failure stands: each ran, did not converge, and no later step
        that converged refitted every one of its parameters (:func:`superseding_step`).
        A cap in an early step only means a worse start for the steps after it; the
        joint step refits everything on every recording, so its verdict is the
        result's."""
        return [s for s in self.steps if s.result is not None and not s.converged
                and superseding_step(self.steps, s) is None]

    @property
    def converged(self) -> bool:
        """True when no step's failure stands (:attr:`unconverged_steps`) and the data
        determine every parameter of the steps asked for (never on untouched start
        values)."""
        blocked = self.undetermined is not None and bool(self.undetermined.blocking)
        return not blocked and not self.unconverged_steps


def superseding_step(steps: Sequence[StepReport], step: StepReport) -> StepReport | None:
    """The first step after ``step`` in ``steps`` that converged with every parameter of
    ``step`` free (so ``step``'s end point is not the result), or None."""
    later = steps[steps.index(step) + 1:]
    return next((s for s in later if s.converged and set(step.free) <= set(s.free)), None)


REPLAN_FACTOR = 2
"""A step re-plans its sub-steps (:func:`_solve_step`) once the model it has reached
needs at most 1/``REPLAN_FACTOR`` of the sub-steps per sample it runs with. A plan is
made from a step's start, and a start bent toward a fast mode by the step before (the
dynamics step on one step response can take the piezo's mass down 3-35x, to a mode at
27-61 kHz, where 39-52 sub-steps per sample are needed instead of 7-9; the joint step
on every recording takes it back) would price every later evaluation of the step at
that many; re-planning costs one more compiled simulation, worth it when what is left
runs at half the sub-steps or fewer."""


def _solve_step(name: str, act: Actuator, free: list[str], extra: dict, sub: Dataset,
                rows: list[int], weights: dict, stepping: StepPlan, programs, max_steps: int,
                say: Callable[[str], None]):
    """Solve one identification step from ``act`` with ``stepping``, re-planning the
    sub-steps when the fit reaches a model that needs far fewer
    (:data:`REPLAN_FACTOR`): the solve is interrupted there and goes on from that point
    with the new plan and the damping it had, within ``max_steps`` in all. Returns
    ``(actuator, plan, residuals, evaluator, result, segments)``: ``plan``,
    ``residuals`` and ``evaluator`` of the last segment, the result joined over the
    segments (steps, time and evaluations summed, the start's cost and residual from
    the first), and each segment's plan and evaluations (:class:`PlanSegment`)."""
    settings = STEP_SOLVE.get(name, LMSettings())
    parts: list[SolveResult] = []
    segments: list[PlanSegment] = []
    while True:
        pmap = ParameterMap.make(act, free, extra)
        res = TraceResiduals.make(pmap, sub, stepping=stepping, **weights)
        evaluator = StepJacobian(res, programs, rows) if programs is not None else None

        def coarser(theta, pmap=pmap, plan=stepping):
            need = dataset_plan(pmap.actuator(theta, xp=np), sub)
            if (need.substeps * REPLAN_FACTOR <= plan.substeps
                    and dataclasses.replace(need, substeps=plan.substeps) == plan):
                return (f"the model reached needs {need.substeps} sub-steps per sample, "
                        f"not {plan.substeps}")
            return ""

        left = max_steps - sum(p.iterations for p in parts)
        out = solve_least_squares(res, pmap.zeros(), settings.replace(max_steps=left),
                                  label=name, echo=say, jacobian=evaluator,
                                  value=evaluator.value if evaluator is not None else None,
                                  stop_when=coarser)
        act = (evaluator.actuator(out.theta) if evaluator is not None
               else pmap.actuator(jnp.asarray(out.theta)))
        parts.append(out)
        segments.append(PlanSegment(stepping, int(out.jacobians), int(out.values)))
        if not out.interrupted or out.iterations >= left:
            break
        stepping = dataset_plan(act, sub)
        say(f"[{name}] re-planned: {out.interrupted}; going on with {stepping.substeps}")
        settings = settings.replace(initial_damping=out.damping)
    first, total = parts[0], sum(p.iterations for p in parts)
    # Interrupted at its last step, or its last segment at the steps left: the step's
    # own cap.
    capped = out.interrupted or (out.status is SolveStatus.STEP_CAP and total >= max_steps)
    message = f"not converged: hit max_steps={max_steps}" if capped else out.message
    status = SolveStatus.STEP_CAP if capped else out.status
    if len(parts) > 1:
        message = f"{message}; re-planned {len(parts) - 1}x"
    if message != out.message:
        out = dataclasses.replace(
            out, status=status, message=message, iterations=total,
            wall_s=sum(p.wall_s for p in parts),
            cost_start=first.cost_start, residual_start=first.residual_start,
            jacobians=sum(p.jacobians for p in parts), values=sum(p.values for p in parts))
    return act, stepping, res, evaluator, out, segments


def _is_step(r):
    return r.drive.waveform == "step"


def _is_sine(r):
    return r.drive.waveform == "sine"


def _is_saw(r):
    return r.drive.waveform == "sawtooth"


def _apply_fixed(actuator: Actuator, fixed: dict[str, float]) -> Actuator:
    for name, value in fixed.items():
        actuator = eqx.tree_at(parameter_getter(name, actuator), actuator,
                               jnp.asarray(float(value)))
    return actuator


@one_blas_thread
def identify(
    recordings: Sequence,
    *,
    init: Actuator,
    fix: dict[str, float] | None = None,
    steps: Sequence[str] = STEPS,
    n_pi: int = 35,
    free_ratio: bool = False,
    fit_rho1: bool = False,
    also_fit: Sequence[str] = (),
    max_steps: int = 60,
    w_psd: float = DEFAULT_W_PSD,
    extra: dict[str, ParameterSpec] | None = None,
    uncertainty: bool = True,
    spread_if_mismatch: bool = False,
    keep_thresholds: bool = False,
    echo: Callable[[str], None] | None = None,
) -> Identification:
    """Identify an actuator from recordings (see the module docstring).

    ``init`` the starting actuator (a friction law with parameters flagged for the
    steps: the paper's elasto-plastic law, or any registered law that flags its own);
    ``fix`` names held at given SI values; ``steps`` which of ``dynamics, hysteresis,
    friction, joint`` to run, in that order; ``n_pi`` play operators over the recorded
    voltage range when a step asked for fits the PI weights (otherwise, or with
    ``keep_thresholds``, the start's thresholds are kept); ``also_fit`` the law's
    on-request parameters to fit as well
    (``free_ratio`` is ``zba_ratio``, ``fit_rho1`` is ``rho1``); ``w_psd``
    weight of the step-response log-PSD term (see :class:`TraceResiduals`);
    ``extra`` quantities of a model extension already in ``init`` (name → spec), fitted
    in every step beside that step's own (the diagnosis re-identifies a baseline with
    an entry attached); ``uncertainty`` False skips the parameter uncertainty (one
    Jacobian on every recording unless the joint step ran last);
    ``spread_if_mismatch`` repeats the joint step once per regime left out when the
    residual is beyond the noise (:mod:`.model_check`, :mod:`.regime_spread`: a better
    measure of the error than the standard errors then; a few joint fits more);
    ``echo`` receives progress lines.
    """
    require_float64("identify")
    extra = dict(extra or {})
    say = echo or (lambda s: None)
    fix = dict(fix or {})
    unknown = [s for s in steps if s not in STEPS]
    if unknown:
        raise ValueError(f"unknown step(s) {unknown}; choose from {', '.join(STEPS)}")
    if not any(p.step for p in law_fittable(init)):
        raise ValueError(f"identification fits a friction law whose parameters name the "
                         f"steps that fit them; the starting parameters' law "
                         f"({type(init.friction).__name__}) names none")
    requested = requested_names(init, [*also_fit, *(["zba_ratio"] if free_ratio else []),
                                  *(["rho1"] if fit_rho1 else [])])
    cannot = [n for n in fix if n not in fittable_names(init) or n == "pi_weights"]
    if cannot:
        raise ValueError(f"cannot hold {', '.join(cannot)}: not a scalar the identification "
                         f"fits with the {type(init.friction).__name__} law; those are: "
                         f"{', '.join(fittable_names(init)[:-1])}")
    data = Dataset.from_recordings(recordings)
    check_sample_rates(data.recordings, init)  # before anything is fitted
    notes: list[str] = []
    scale_free = scale_invariant_names(init)
    if not any(n in fix for n in scale_free):
        fix["Ms"] = float(init.slider.Ms)
        notes.append(
            f"Position data determine {', '.join(scale_free)} only up to one "
            f"common factor. Ms was held at {fix['Ms']:g} kg (the starting value); pass "
            f"--fix Ms=<weighed mass> (or fix another of them) to set the scale.")
    act = _apply_fixed(init, fix)
    # Before any fitting: what the data cannot determine is neither fitted nor reported.
    informative = assess(data.recordings, init, steps=steps, fix=fix, also_fit=requested,
                         n_pi=n_pi)
    notes += [g.line() for g in informative.groups if not g.blocking]
    if informative.blocking:
        say(f"[data] undetermined by these recordings: "
            f"{', '.join(n for g in informative.blocking for n in g.names)}; nothing fitted")
        return Identification(act, [StepReport(s, [], [], None, np.nan, np.nan,
                                               "skipped: the data cannot determine it")
                                    for s in STEPS if s in steps],
                              data, np.full(len(data), np.nan), None,
                              notes + [informative.statement()], None, fix,
                              undetermined=informative)
    if ("hysteresis" in steps or "joint" in steps) and not keep_thresholds:
        # Fitted: n_pi thresholds over the recorded voltages. Held (or asked to keep
        # them), the start's hysteresis keeps its grid (a new one changes the model).
        act = pi_over_range(act, data.recordings, n_pi)

    step_recs = [r for r in data.recordings if _is_step(r)]
    slow = [r for r in data.recordings if _is_sine(r)] or step_recs
    # Start-up estimates only for the steps that start from a rough guess.
    if slow and ("dynamics" in steps or "hysteresis" in steps):
        act, gain = scale_pi_quasistatic(act, slow[0])
        notes.append(f"Start: PI weights scaled by {gain:.3g} to the stroke of {slow[0].name}.")
    if step_recs and "dynamics" in steps:
        mode = measured_step_mode(step_recs[0])
        if mode is None:
            notes.append("Start: no clear ringing after the step edge; the starting "
                         "stiffnesses and dampings were kept.")
        else:
            act, k, d = scale_to_step_mode(act, *mode)
            notes.append(f"Start: step ringing measured at {mode[0]:.0f} Hz (damping ratio "
                         f"{mode[1]:.2f}); stiffnesses scaled by {k:.3g}, dampings by {d:.3g}.")

    def free_dynamics():
        return dynamics_names(act, fix=fix, also_fit=requested)

    def free_friction():
        return friction_names(act, fix=fix, also_fit=requested)

    def step_breakaway():
        # A fast step edge makes the slider slip, so the breakaway of the step's
        # direction shapes the step response as much as the dynamics do.
        return breakaway_names(act, step_recs, fix=fix)

    recipe = {
        "dynamics": (_is_step, free_dynamics() + step_breakaway(), dict(w_psd=w_psd)),
        "hysteresis": (_is_sine, ["pi_weights"], {}),
        "friction": (_is_saw, free_friction(), dict(w_steps=1.0)),
        # The joint step is the estimate: the maximum-likelihood residual (every sample
        # weighted by its recording's noise, no PSD or step-length terms), converged by
        # the Gauss-Newton test, so that its Jacobian gives the covariance.
        "joint": (lambda r: True, free_dynamics() + ["pi_weights"] + free_friction(),
                  dict(whiten=True)),
    }
    # What each step asked for fits, on which recordings (indices into ``data``).
    chosen = {}
    for name in (n for n in STEPS if n in steps):
        keep, free, weights = recipe[name]
        free = free + list(extra)
        rows = [b for b, r in enumerate(data.recordings) if keep(r)]
        # Only directions present in the data can be fitted.
        if name in ("friction", "joint"):
            free = without_absent_directions(free, act, [data.recordings[b] for b in rows])
        chosen[name] = (rows, free, weights)
    free_all = free_dynamics() + ["pi_weights"] + free_friction() + list(extra)
    # One compiled simulation for every step (.sensitivities): on a CPU, where the
    # recordings run one by one anyway; accelerators batch each step's recordings.
    programs = None
    if default_batching() == "map":
        union = list(dict.fromkeys([n for _, f, _ in chosen.values() for n in f] + free_all))
        programs = RecordingPrograms(data, act, perturbed_mask(act, union, extra))

    reports: list[StepReport] = []
    last = None  # (residual function, solve result, evaluator) of the last step that ran
    stepping = None  # the sub-steps of the last step that ran
    for name, (rows, free, weights) in chosen.items():
        if not rows or not free:
            reports.append(StepReport(name, [], free, None, np.nan, np.nan,
                                      "skipped: no recordings of this kind"
                                      if not rows else "skipped: nothing free"))
            say(f"[{name}] skipped ({reports[-1].note})")
            continue
        subset = [data.recordings[b] for b in rows]
        sub = Dataset.from_recordings(subset)
        stepping = kept_finer(dataset_plan(act, sub), stepping)
        if programs is not None and not reports:
            # The wide steps' program and the error estimate's, compiled beside the
            # first step (they wait for nothing it computes; on one core, no gain);
            # the wide one only where a later Jacobian runs it.
            later = [f for n, (r, f, _) in chosen.items() if n != name and r and f]
            wide = any(programs.goes_wide(mask_size(act, perturbed_mask(act, f, extra)))
                       for f in later + ([free_all] if uncertainty else []))
            programs.prefetch(act, kept_finer(dataset_plan(act, data), stepping),
                              wide=wide)
        say(f"[{name}] {len(subset)} recording(s), free: {', '.join(free)}")
        act, stepping, res, evaluator, out, segments = _solve_step(
            name, act, free, extra, sub, rows, weights, stepping, programs, max_steps, say)
        # NRMSEs from the residuals the solver evaluated (no extra simulation).
        before = float(res.nrmse_from_residual(out.residual_start).mean())
        after = float(res.nrmse_from_residual(out.residual).mean())
        say(f"[{name}] {out.message} after {out.iterations} steps, {out.wall_s:.1f} s; "
            f"NRMSE {100 * before:.3f} % -> {100 * after:.3f} %")
        reports.append(StepReport(name, [r.name for r in subset], free, out, before, after,
                                  segments=segments))
        last = (res, out, evaluator)
    notes += [f"Step '{s.name}' {s.result.message}; the '{later.name}' step, which refitted "
              f"all of its parameters, converged, so its end point is the result."
              for s in reports if s.result is not None and not s.converged
              and (later := superseding_step(reports, s)) is not None]

    def simulated(actuator, plan):
        if programs is not None:
            return programs.simulate(actuator, plan)
        return np.asarray(eqx.filter_jit(lambda a: simulate_dataset(a, data, plan=plan))(
            actuator))

    if not uncertainty:
        plan = kept_finer(dataset_plan(act, data), stepping)
        q_sim = simulated(act, plan)
        numerical = numerical_error(act, data, plan, q_sim, programs=programs)
        return Identification(act, reports, data, nrmse_per_recording(q_sim, data), None,
                              notes, q_sim, fix, numerical, undetermined=informative,
                              plan=plan, model_check=check_model(data, q_sim, numerical))
    # Final evaluation and uncertainty on every recording with every fitted quantity.
    t0 = time.perf_counter()
    q_sim = None
    if (last is not None and len(last[0].data) == len(data)
            and list(last[0].pmap.names) == free_all):
        # The joint step fitted exactly this: its solver already holds the Jacobian at
        # the optimum; its time rows, unscaled to metres, are the uncertainty's.
        say("[uncertainty] from the joint step's Jacobian at the optimum")
        res, out, evaluator = last
        pmap, theta = res.pmap, jnp.asarray(out.theta)
        jac, resid = out.jacobian, out.residual
        if evaluator is not None:
            q_sim = evaluator.outputs_at(out.theta)  # simulated with the Jacobian there
    else:
        say("[uncertainty] Jacobian at the optimum...")
        res = TraceResiduals.make(ParameterMap.make(act, free_all, extra), data,
                                  stepping=kept_finer(dataset_plan(act, data), stepping),
                                  whiten=True)
        pmap, theta = res.pmap, res.pmap.zeros()
        if programs is not None:
            evaluator = StepJacobian(res, programs, range(len(data)))
            resid, jac = (np.asarray(x) for x in evaluator(theta))
            q_sim = evaluator.outputs_at(theta)
        else:
            resid, jac = value_and_jacobian(res, theta)
    # ``act`` is the actuator at θ (the last step's result, or the start of this one).
    plan = kept_finer(dataset_plan(act, data), stepping)
    if q_sim is None or plan != res.plan:
        q_sim = simulated(act, plan)
    phys = pmap.physical(theta)
    values = np.concatenate([np.atleast_1d(phys[n]) for n in pmap.names])
    # Real samples minus one fitted offset per recording.
    n_obs = int(data.mask.sum()) - len(data)
    unc = parameter_uncertainty(jac, resid, pmap.value_jacobian(theta), values, pmap.labels(),
                                n_obs=n_obs, mask=data.mask)
    # The residual's spread in metres (the whitened one's is in units of the noise).
    metres = res.in_metres_rows(resid)
    unc = dataclasses.replace(unc, sigma=float(np.sqrt(np.sum(metres**2) / unc.dof)))
    say(f"[uncertainty] done in {time.perf_counter() - t0:.1f} s")
    u_top = max(float(np.max(r.voltage_V)) for r in data.recordings)
    fitted_pi = any("pi_weights" in r.free for r in reports if r.result is not None)
    curve = loading_curve_uncertainty(pmap, theta, unc, u_top) if fitted_pi else None
    nrmse = nrmse_per_recording(q_sim, data)
    numerical = numerical_error(act, data, plan, q_sim, programs=programs)
    say(f"[numerics] simulator error at the fit (step doubling): at most "
        f"{numerical.max() * 1e9:.3g} nm RMS per recording")
    check = check_model(data, q_sim, numerical)
    say(f"[check] {check.statement()}")
    joint = next((r for r in reports if r.name == "joint" and r.result is not None), None)
    spread = None
    if spread_if_mismatch and not check.adequate and joint is not None:
        spread = regime_spread(
            data.recordings, joint.free,
            _refit_without(act, data, extra, stepping, programs, max_steps, say),
            lambda recs: assess(recs, act, steps=("joint",), fix=fix, also_fit=requested,
                                n_pi=n_pi).names, say)
    return Identification(act, reports, data, nrmse, unc, notes, q_sim, fix, numerical,
                          loading_curve=curve, undetermined=informative, plan=plan,
                          model_check=check, regime_spread=spread)


def _refit_without(act: Actuator, data: Dataset, extra: dict, stepping: StepPlan | None,
                   programs, max_steps: int, say: Callable[[str], None]) -> Refit:
    """The joint step again on a subset of ``data``'s recordings from ``act`` (the full
    fit), as :func:`~.regime_spread.regime_spread` asks for it."""

    def refit(rows: list[int], names: list[str]):
        sub = Dataset.from_recordings([data.recordings[b] for b in rows])
        plan = kept_finer(dataset_plan(act, sub), stepping)
        _, _, res, _, out, _ = _solve_step("joint", act, names, extra, sub, rows,
                                           dict(whiten=True), plan, programs, max_steps,
                                           lambda s: None)
        say(f"[spread] {out.message} after {out.iterations} steps")
        phys = res.pmap.physical(out.theta)
        values = np.concatenate([np.atleast_1d(phys[n]) for n in res.pmap.names])
        return (dict(zip(res.pmap.labels(), map(float, values), strict=True)),
                bool(out.converged), out.message)

    return refit
