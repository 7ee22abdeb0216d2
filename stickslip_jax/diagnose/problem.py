"""The whitened problem: the data, each recording's noise level, and the noise-whitened
time-domain residual of any actuator, the metric every comparison of the diagnosis uses;
every simulation it runs is charged to the work budget (:mod:`.budget`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..identify.dataset import Dataset
from ..identify.parameters import ParameterMap
from ..identify.residuals import TraceResiduals, dataset_plan, default_batching
from ..identify.sensitivities import (
    RecordingPrograms,
    StepJacobian,
    perturbed_mask,
    sensor_only_columns,
)
from ..identify.solve import (
    ColumnSplitJacobian,
    LMSettings,
    SolveResult,
    solve_least_squares,
)
from ..identify.step_names import dynamics_names, friction_names, without_absent_directions
from ..identify.steps import JOINT_GN_TOL, REPLAN_FACTOR, kept_finer
from ..model.actuator import Actuator
from ..noise import noise_sigma
from ..program_store import stored_jit
from ..significance import Significance
from ..stepping import MAX_SUBSTEPS_PER_CALL, StepPlan
from .budget import UNIT, Budget, evaluation_work, fit_work, plan_factor, solve_work


class WhitenedResiduals(eqx.Module):
    """``θ ↦`` residual samples divided by each recording's noise level [-]: the
    offset-removed ``measured − simulated`` of every real sample over σ (padding 0)."""

    inner: TraceResiduals
    inv_sigma: jax.Array

    def __call__(self, theta, args=None):
        return self.whiten(self.inner(theta))

    def whiten(self, r):
        """In-metres residual vector ``r`` → divided by each recording's σ."""
        r = r.reshape(self.inv_sigma.shape[0], -1)
        return (r * self.inv_sigma[:, None]).reshape(-1)


def without_span(basis, x):
    """``x`` (a vector, or columns) less its part in the span of ``basis`` (orthonormal
    columns): ``x − B(Bᵀx)``; numpy or JAX arrays."""
    return x - basis @ (basis.T @ x)


FIRST_ORDER_REACH = 1.0
"""The largest move [θ] of any baseline coordinate for which the baseline's linearised
response is trusted: a factor e of a quantity fitted in logarithm (the dynamics, the
PI weights through their partial sums). A first-order move beyond it is
extrapolation: the linearised baseline can then "restore" a trace the entry has
destroyed (a drive lag of hours, the output scaled back by PI weights moved a
millionfold), a fall of the cost no refit can have."""


@dataclass(frozen=True)
class BaselineSpan:
    """The span of the baseline's whitened Jacobian ``J_b`` (samples × its fitted
    quantities' θ, :func:`of`): what the baseline can mimic to first order, and how far
    it moves to do so.

    ``basis``: orthonormal columns spanning ``J_b`` (Q of the QR of ``J_b`` with unit
    columns); ``triangle``: that R; ``norms``: ``J_b``'s column norms."""

    basis: np.ndarray
    triangle: np.ndarray
    norms: np.ndarray

    @classmethod
    def of(cls, jacobian) -> BaselineSpan:
        jacobian = np.asarray(jacobian, dtype=float)
        norms = np.linalg.norm(jacobian, axis=0)
        q, r = np.linalg.qr(jacobian / np.where(norms > 0, norms, 1.0))
        return cls(q, r, norms)

    def move(self, residual) -> np.ndarray:
        """The baseline's first-order move δ [θ] that takes out the part of
        ``residual`` in the span: ``argmin |residual + J_b·δ|``, the least-norm one
        (singular values below 1e-10 of the largest dropped, as a poorly determined
        direction moves nowhere)."""
        step = np.linalg.lstsq(self.triangle, -(self.basis.T @ np.asarray(residual)),
                               rcond=1e-10)[0]
        return step / np.where(self.norms > 0, self.norms, 1.0)

    def reach(self, residual) -> float:
        """The largest |δ| of :meth:`move` [θ]: within :data:`FIRST_ORDER_REACH`, the
        first-order response is the baseline's; beyond, extrapolation."""
        return largest_move(self.move(residual))


def largest_move(move) -> float:
    """The largest |δ| of a baseline move ``move`` [θ] (0 for none)."""
    return float(np.max(np.abs(np.asarray(move)), initial=0.0))


class ProjectedResiduals(eqx.Module):
    """``θ ↦`` the whitened residual less its part in the span of ``basis`` (columns
    orthonormal, one row per residual sample): ``r − B(Bᵀr)`` [-]. With ``B`` spanning
    the baseline's Jacobian, its sum of squares is the cost with the baseline free to
    first order, ``min_δ |r + J_b δ|²`` (variable projection), without fitting the
    baseline's tens of parameters."""

    inner: WhitenedResiduals
    basis: jax.Array

    def __call__(self, theta, args=None):
        return without_span(self.basis, self.inner(theta, args))


@dataclass(frozen=True)
class FitSolve(SolveResult):
    """A fit's :class:`~stickslip_jax.identify.solve.SolveResult` with the coordinates
    it was solved in: ``theta`` and ``jacobian`` are over ``pmap``'s θ (what turns a
    draw of θ into values: :mod:`.form_band`)."""

    pmap: ParameterMap | None = None


class FitProgram:
    """``θ ↦ (whitened residual, ∂/∂θ)`` of the quantities of ``pmap`` around its start,
    in numpy.

    On a CPU, from the problem's shared programs (:meth:`Problem.recording_programs`),
    as an identification step evaluates its residual
    (:class:`~stickslip_jax.identify.sensitivities.StepJacobian`), then whitened.
    Nothing is compiled per fit there. XLA's tracing and compiling of one program per
    fit over the whole data set (its arrays constants of the program, its length
    buckets copies of the sample loop) was most of a diagnosis's wall time (565 of
    770 s on a 17-recording set, 181 programs); the shared programs simulate one
    recording with everything that differs between fits as an argument, so every fit
    on one actuator structure and stepping plan runs the same two programs.

    On an accelerator, which batches the recordings in one call, one program over the
    whole set (:class:`~stickslip_jax.identify.solve.ColumnSplitJacobian`), as the
    identification's steps do there."""

    def __init__(self, problem: Problem, pmap: ParameterMap, specs: dict | None = None):
        self.pmap = pmap
        self.residuals = problem.residuals(pmap)
        self.factor = problem.plan_factor(pmap.start, self.residuals.inner.plan)
        """Its :meth:`~Problem.plan_factor`, at the plan it keeps."""
        self.programs: RecordingPrograms | None = None
        """The shared programs it runs (None on an accelerator)."""
        self._shared = self._batched = None
        self.simulated_columns = pmap.size
        """Columns of its Jacobian that ride on the mechanics' pass, what the work budget
        charges (:func:`~.budget.evaluation_work`): on a CPU, the sensor's quantities
        are derived apart, at the simulated positions
        (:meth:`~stickslip_jax.identify.sensitivities.RecordingPrograms.sensitivities`),
        and count nothing."""
        if default_batching() == "map":
            self.programs = problem.recording_programs(pmap.start, pmap.names, specs)
            self._shared = StepJacobian(self.residuals.inner, self.programs,
                                        range(len(problem.data)))
            self.simulated_columns = int(np.sum(~sensor_only_columns(
                pmap.leaf_tangents(np.zeros(pmap.size), self.programs.mask))))
        else:
            self._batched = ColumnSplitJacobian(self.residuals)

    def __call__(self, theta) -> tuple[np.ndarray, np.ndarray]:
        if self._batched is not None:
            r, jac = self._batched(jnp.asarray(theta, dtype=float))
            return np.asarray(r), np.asarray(jac)
        r, jac = self._shared(theta)  # in metres
        weight = self._weight(r.size)
        return r * weight, jac * weight[:, None]

    def _weight(self, size: int) -> np.ndarray:
        inv_sigma = np.asarray(self.residuals.inv_sigma)
        return np.repeat(inv_sigma, size // len(inv_sigma))

    @property
    def value(self):
        """``θ ↦`` the whitened residual alone, through the value-only shared program
        (None on an accelerator, whose one program gives both)."""
        if self._shared is None:
            return None

        def value(theta):
            r = self._shared.value(theta)
            return r * self._weight(r.size)
        return value


@stored_jit
def _simulated(res: WhitenedResiduals):
    """Simulated outputs (B, T) [m] at ``res``'s actuator, every recording in one
    batched program (accelerators)."""
    return res.inner.simulate(jnp.zeros(0))


def recentred(jacobian: np.ndarray, pmap: ParameterMap, theta,
              specs: dict | None = None) -> np.ndarray | None:
    """A Jacobian ``∂r/∂θ`` of ``pmap``'s quantities at ``theta``, in the coordinates of
    the same quantities around the actuator there (``θ = 0`` at it, what
    :meth:`Problem.program` of that actuator uses): ``J·V(θ)⁻¹·V₀`` with ``V`` the
    derivatives of the physical values in either coordinates
    (:meth:`~stickslip_jax.identify.parameters.ParameterMap.value_jacobian`), so a
    fit's last Jacobian serves at its optimum without simulating again. None where
    the change of coordinates is singular or not finite at ``theta``."""
    theta = np.asarray(theta, dtype=float)
    here = ParameterMap.make(pmap.actuator(theta, xp=np), pmap.names, specs)
    try:
        change = np.linalg.solve(pmap.value_jacobian(theta),
                                 here.value_jacobian(np.zeros(here.size)))
    except np.linalg.LinAlgError:
        change = None
    if change is None or not np.all(np.isfinite(change)):
        # A coordinate whose transform has flattened (a logit or softplus far into its
        # tail, a PI weight's sum underflowed) has no direction to carry over: the
        # caller simulates the Jacobian where it needs one.
        return None
    return np.asarray(jacobian) @ change


def baseline_free(act: Actuator, data: Dataset, fix: dict) -> list[str]:
    """The baseline's fitted quantities: dynamics (less the fixed ones), the PI
    weights, the friction law's friction-step quantities (z_ba for each direction
    present), as the identification's joint step frees them by default."""
    names = dynamics_names(act, fix=fix) + ["pi_weights"] + friction_names(act, fix=fix)
    return [n for n in without_absent_directions(names, act, data.recordings)
            if n not in fix]


class Problem:
    """The data, the noise levels and the whitened residual of any actuator; every
    simulation it runs is charged to ``budget`` (:mod:`.budget`)."""

    def __init__(self, data: Dataset, sigmas: np.ndarray, fix: dict, echo,
                 budget: Budget | None = None, gauss_newton_trial: bool = True):
        self.data, self.sigmas, self.fix, self.say = data, sigmas, fix, echo
        self.budget = budget or Budget(None)
        self.gauss_newton_trial = gauss_newton_trial
        """Whether the fits try the full Gauss-Newton point after a step the linear
        model predicted (:class:`~stickslip_jax.identify.solve.LMSettings`)."""
        self.n_obs = int(data.mask.sum())
        self.samples = int(data.mask.size)  # the padded grid the simulator steps
        self.counts = np.asarray(data.mask.sum(axis=1), dtype=float)
        self._programs: dict = {}
        self._plans: list[StepPlan] = []
        """The stepping plans this problem's fits have run at, coarsest first
        (:meth:`plan_for`)."""
        self.significance: Significance | None = None
        """The tolerance of practical significance (:mod:`~stickslip_jax.significance`),
        set once the baseline's numerical error is known."""

    @classmethod
    def whitened(cls, data: Dataset, fix: dict, echo=None, budget: Budget | None = None,
                 **options) -> Problem:
        """The problem of ``data``, each recording whitened by its own noise level
        estimated from it (:func:`~stickslip_jax.noise.noise_sigma`, [m]); ``options`` as
        the constructor's (``gauss_newton_trial``)."""
        sigmas = np.array([noise_sigma(r) for r in data.recordings])
        return cls(data, sigmas, fix, echo, budget, **options)

    def plan_for(self, act: Actuator, *, keep: bool = True) -> StepPlan:
        """The stepping plan a simulation of ``act`` on these data runs at: the plan it
        needs (:func:`~stickslip_jax.identify.residuals.dataset_plan`), or the coarsest
        one this problem already ran at by the same rules with at least as many
        sub-steps and fewer than :data:`~stickslip_jax.identify.steps.REPLAN_FACTOR`
        times as many, as an identification step keeps its plan until the fit needs
        half of it or less. The sub-step count is static in the compiled programs, and a
        fit that moves the fastest mode across a count's boundary (the reduced sensor
        delay set: 7 and 8 sub-steps in turn) compiled every structure's programs twice;
        a finer plan is never less accurate. ``keep``: remember a new plan (False for an
        estimate of a fit that may not run)."""
        need = dataset_plan(act, self.data)
        for used in self._plans:
            if (kept_finer(need, used) is used
                    and used.substeps < REPLAN_FACTOR * need.substeps
                    and used.substeps * self.samples <= MAX_SUBSTEPS_PER_CALL):
                return used
        if keep:
            self._plans = sorted([*self._plans, need], key=lambda p: p.substeps)
        return need

    def plan_factor(self, act: Actuator, plan: StepPlan | None = None) -> float:
        """Cost per sample of simulating ``act`` at ``plan`` (default: the plan it runs
        at on these data, :meth:`plan_for`; pass a residual's own, ``res.inner.plan``,
        when there is one), relative to the work unit's (:func:`~.budget.plan_factor`)
        [-]."""
        plan = self.plan_for(act, keep=False) if plan is None else plan
        return plan_factor(plan, act.input_stage)

    def identification_work(self, ident, start: Actuator) -> float:
        """:func:`identification_work` of ``ident``, an identification started from
        ``start`` (whose drive stage it kept), on these data [sample-evaluations]."""
        return identification_work(ident, self.data,
                                   lambda plan: self.plan_factor(start, plan))

    def evaluation_work(self, act: Actuator, columns: int) -> float:
        """One evaluation of the residual of ``act`` with a Jacobian of ``columns``
        columns [sample-evaluations]."""
        return evaluation_work(self.samples, columns, self.plan_factor(act))

    def fit_estimate(self, act: Actuator, columns: int, max_steps: int) -> float:
        """The most a fit of ``columns`` parameters from ``act`` can cost
        [sample-evaluations], known before it runs (at the plan of ``act``, which the
        fit keeps)."""
        return fit_work(self.samples, columns, max_steps, self.plan_factor(act))

    def refit_estimate(self, act: Actuator, columns: int, max_steps: int) -> float:
        """The most a refit (:meth:`refit`) of ``columns`` parameters from ``act`` can
        cost [sample-evaluations]: both its stages at ``max_steps``."""
        held = int(np.size(act.hysteresis.weights))
        factor = self.plan_factor(act)  # one plan for both stages' estimates
        return (fit_work(self.samples, max(columns - held, 1), max_steps, factor)
                + fit_work(self.samples, columns, max_steps, factor))

    def recording_programs(self, act: Actuator, names: Sequence[str] = (),
                           specs: dict | None = None) -> RecordingPrograms:
        """The shared programs (:class:`~stickslip_jax.identify.sensitivities.
        RecordingPrograms`) of the data for actuators of the structure of ``act``, their
        tangents covering the baseline's free quantities (:func:`baseline_free`) and
        ``names`` (``specs`` for those not built in), kept for every later fit on that
        structure. A name not covered yet widens them (one more compile; every fit of a
        diagnosis on one structure otherwise shares them, whatever it frees)."""
        key = jax.tree.structure(act)
        covered, known, programs = self._programs.get(key, (set(), {}, None))
        if programs is not None and set(names) <= covered:
            return programs
        known.update({n: specs[n] for n in names if specs and n in specs})
        covered = covered | set(baseline_free(act, self.data, self.fix)) | set(names)
        programs = RecordingPrograms(self.data, act, perturbed_mask(act, sorted(covered), known))
        self._programs[key] = (covered, known, programs)
        return programs

    def residuals(self, pmap: ParameterMap) -> WhitenedResiduals:
        """The whitened residual around ``pmap``, at the plan of its start
        (:meth:`plan_for`)."""
        inner = TraceResiduals.make(pmap, self.data, in_metres=True,
                                    stepping=self.plan_for(pmap.start))
        return WhitenedResiduals(inner, jnp.asarray(1.0 / self.sigmas))

    def evaluate(self, act: Actuator):
        """(whitened RSS, NRMSE per recording, simulated outputs) of ``act``."""
        r, q = self.whitened_residual(act)
        return float(r @ r), self.nrmse_from_whitened(r), q

    def whitened_residual(self, act: Actuator) -> tuple[np.ndarray, np.ndarray]:
        """The whitened residual of ``act`` (padding 0) and its simulated outputs
        (B, T) [m], from one value-only simulation."""
        res = self.residuals(ParameterMap.make(act, []))
        if default_batching() == "map":
            q = self.recording_programs(act).simulate(act, res.inner.plan)
        else:
            q = np.asarray(_simulated(res))
        r = res.whiten(res.inner.from_output(q, xp=np))
        self.budget.charge(evaluation_work(self.samples, 0,
                                           self.plan_factor(act, res.inner.plan)))
        return np.asarray(r), np.asarray(q)

    def chi2_per_recording(self, nrmse) -> np.ndarray:
        """Mean ``(e/σ)²`` per recording from its NRMSE [-] (:meth:`nrmse_from_whitened`)."""
        return (np.asarray(nrmse) * np.asarray(self.data.scale) / self.sigmas) ** 2

    def cost_of_output(self, act: Actuator, q) -> float:
        """Whitened RSS of outputs ``q`` (B, T) [m] already simulated for ``act``."""
        res = self.residuals(ParameterMap.make(act, []))
        r = res.whiten(res.inner.from_output(np.asarray(q), xp=np))
        return float(r @ r)

    def nrmse_from_whitened(self, r) -> np.ndarray:
        """NRMSE per recording [-] from a whitened residual vector (no simulation)."""
        d = self.data
        rows = np.asarray(r).reshape(len(d), -1) * self.sigmas[:, None]
        n = np.sum(d.mask, axis=-1)
        return np.sqrt(np.sum(rows**2, axis=1) / n) / np.asarray(d.scale)

    def program(self, act: Actuator, names: Sequence[str], specs: dict) -> FitProgram:
        """The residual and Jacobian program of ``names`` around ``act``
        (:class:`FitProgram`), for :meth:`fit_from`."""
        return FitProgram(self, ParameterMap.make(act, list(names), specs), specs)

    def fit(self, act: Actuator, names: Sequence[str], specs: dict, *, label: str,
            max_steps: int, initial_damping: float = 1.0,
            project: np.ndarray | None = None,
            admit: Callable[[FitProgram], None] | None = None,
            ) -> tuple[Actuator, float, object]:
        """Least squares of the whitened residual over ``names`` from ``act``
        (:meth:`fit_from` on a new :meth:`program`).

        It ends by the Gauss-Newton test (:data:`~stickslip_jax.identify.steps.
        JOINT_GN_TOL`: the full Gauss-Newton step from the point is shorter than a
        tenth of a standard error; a step within what the parameters' domains allow,
        :meth:`~stickslip_jax.identify.parameters.ParameterMap.step_bounds`), so that a
        fit said to converge is at its minimiser, or at a weight's bound, to a tenth
        of the errors the data allow, whatever its start; one that is not
        there after ``max_steps`` says so. ``initial_damping``: the LM damping at the
        start (small for a start near the optimum). ``project``: an orthonormal
        basis (samples × k) whose span is taken out of the residual
        (:class:`ProjectedResiduals`); the cost returned is then the projected one.
        ``admit``: called with the program (its plan known) before the fit runs; it
        raises to refuse it (:meth:`refit`'s budget check)."""
        program = self.program(act, names, specs)
        if admit is not None:
            admit(program)
        return self.fit_from(program, program.pmap.zeros(), label=label,
                             max_steps=max_steps, initial_damping=initial_damping,
                             project=project)

    def fit_from(self, program: FitProgram, theta0, *, label: str, max_steps: int,
                 initial_damping: float = 1.0,
                 project: np.ndarray | None = None,
                 damping_update: str = "classical") -> tuple[Actuator, float, object]:
        """:meth:`fit` in the coordinates of ``program`` from ``theta0``, with its
        compiled program: a fit that goes on from where another ended (the sizing with
        the baseline free to first order after the held one) compiles nothing.
        ``project`` is applied to the program's residual and Jacobian, in numpy.
        ``damping_update``: how an accepted step changes the LM damping
        (:attr:`~stickslip_jax.identify.solve.LevenbergMarquardtSteps.DAMPING_UPDATES`)."""
        basis = None if project is None else np.asarray(project)

        def jacobian(theta):
            r, jac = program(theta)
            r, jac = np.asarray(r), np.asarray(jac)
            if basis is not None:  # ProjectedResiduals and its Jacobian
                r, jac = without_span(basis, r), without_span(basis, jac)
            return r, jac

        value = program.value
        if value is not None and basis is not None:
            def value(theta, whole=value):
                return without_span(basis, whole(theta))

        res = program.residuals if basis is None else ProjectedResiduals(
            program.residuals, jnp.asarray(basis))
        settings = LMSettings(max_steps=max_steps, gn_tol=JOINT_GN_TOL,
                              initial_damping=initial_damping,
                              damping_update=damping_update,
                              gauss_newton_trial=self.gauss_newton_trial)
        out = solve_least_squares(res, jnp.asarray(theta0, dtype=float), settings,
                                  label=label, echo=None, jacobian=jacobian, value=value,
                                  step_bounds=program.pmap.step_bounds)
        self.budget.charge(solve_work(self.samples, program.simulated_columns, out,
                                      program.factor))
        out = FitSolve(**{f.name: getattr(out, f.name) for f in fields(out)},
                       pmap=program.pmap)
        fitted = program.pmap.actuator(np.asarray(out.theta), xp=np)
        self.say(f"[{label}] {out.message}; {out.iterations} steps, {out.wall_s:.1f} s, "
                 f"cost {out.cost_start:.5g} -> {out.cost_end:.5g}")
        return fitted, float(out.cost_end), out

    def residual_at(self, program: FitProgram, theta) -> np.ndarray:
        """The whitened residual of ``program`` at ``theta``, unprojected (one
        simulation of the data, charged to the budget)."""
        value = program.value
        columns = 0 if value is not None else int(np.size(theta))
        r = value(theta) if value is not None else program(theta)[0]
        self.budget.charge(evaluation_work(self.samples, columns, program.factor))
        return np.asarray(r)

    def refit(self, act: Actuator, names: Sequence[str], specs: dict, *, label: str,
              max_steps: int, reserve: float | None = None, initial_damping: float = 1.0,
              ) -> tuple[Actuator, float, object]:
        """:meth:`fit` over ``names`` in two stages: first with the quantities of
        :data:`HELD_FIRST` (the PI weights) held, then everything from there, starting
        nearly Gauss-Newton (initial damping 1e-3).

        The same minimiser as one fit of everything (the second stage ends by the same
        Gauss-Newton test), reached for less work: the PI weights are most of a refit's
        columns (35 of about 47) and a new entry barely moves the loading curve, so the
        steps that carry the entry to its strength are taken at about a third of the
        columns, and the full fit starts next to its optimum (typically 1-4 steps).
        Returns the second stage's result (its residual and Jacobian at the optimum).
        ``initial_damping``: the first stage's LM damping at its start (small for a
        start that is a fitted model with new parameters at their neutral values).

        Raises ValueError where it starts at, or ends at, a model the simulator cannot
        step on these data: a fit keeps the plan of its start, so it can walk into
        models that plan under-resolves (seen: a slew-limited drive whose time constant
        ran to a pole at 100 MHz when that stage took RK4 steps, costed at the tens of
        stage steps per gap it started with; it advances exactly since 0932ae1, but a
        two-pole drive or a structural mode can still walk so); the cost it reports
        there is the coarse plan's, not the model's, and nothing after it could
        simulate that model.

        ``reserve`` (a budgeted refit; None: not budgeted): raises
        :class:`OverBudget` before the second stage when that stage, at ``max_steps``
        and at the plan of where the first ended, would pass the work budget keeping
        ``reserve``. Its plan is known only then: a first stage that walked into a
        stiff model plans the second at many more sub-steps per sample, and the
        estimate made before the refit, at its start's plan, did not see it (a
        round-two rate-lag refit's second stage ran 3e8 sample-evaluations, 1 500 s,
        to a model with a 1.8 MHz mode)."""
        light = [n for n in names if n not in HELD_FIRST]
        if len(light) == len(names):
            out = self.fit(act, names, specs, label=label, max_steps=max_steps,
                           initial_damping=initial_damping)
        else:
            act, _, _ = self.fit(act, light, specs, label=f"{label}, PI weights held",
                                 max_steps=max_steps, initial_damping=initial_damping)

            def within_budget(program: FitProgram) -> None:
                need = fit_work(self.samples, int(np.size(program.pmap.zeros())),
                                max_steps, program.factor)
                if not self.budget.allows(need, reserve):
                    raise OverBudget(need)
            out = self.fit(act, names, specs, label=label, max_steps=max_steps,
                           initial_damping=1e-3,
                           admit=None if reserve is None else within_budget)
        try:
            self.plan_factor(out[0])
        except ValueError as err:  # (a SteppingError)
            raise ValueError(f"it ended at a model the simulator cannot step on these "
                             f"data: {err}") from err
        return out


class OverBudget(Exception):
    """A budgeted refit's second stage would pass the work budget
    (:meth:`Problem.refit`); ``need``: its estimate [sample-evaluations]."""

    def __init__(self, need: float):
        super().__init__(f"its second stage's {need:.3g} {UNIT}")
        self.need = float(need)


HELD_FIRST = ("pi_weights",)
"""Quantities a refit (:meth:`Problem.refit`) holds in its first stage."""


def segment_work(ident, data: Dataset, factor: Callable[[StepPlan], float]):
    """Each stretch of each step of the identification ``ident`` with its work
    [sample-evaluations]: ``(step, segment, work)`` in the order they ran, a step's
    evaluations on its recordings (padded to the longest of them) with its free
    parameters (:func:`~.budget.solve_work`) at the plan the segment ran at
    (``factor``: the :func:`~.budget.plan_factor` of a plan)."""
    lengths = {r.name: len(r.time_s) for r in data.recordings}
    for st in ident.steps:
        if st.result is None or not st.recordings:
            continue
        samples = len(st.recordings) * max(lengths.get(n, data.mask.shape[1])
                                           for n in st.recordings)
        columns = int(np.size(st.result.theta))
        for seg in st.segments:  # counts its evaluations as a solve result does
            yield st, seg, solve_work(samples, columns, seg, factor(seg.plan))


def identification_work(ident, data: Dataset, factor: Callable[[StepPlan], float]) -> float:
    """The work of an identification [sample-evaluations]: its steps, from the
    evaluations each made on its recordings (padded to the longest of them) with its
    free parameters (:func:`~.budget.solve_work`), each stretch of a step charged at the
    plan it ran at (a step plans its sub-steps from its start and re-plans where its
    fit leaves a fast start: :class:`~stickslip_jax.identify.steps.PlanSegment`); then
    its final simulation of every recording, with the last step's Jacobian when it
    computed an uncertainty, and the step-doubling estimate of its numerical error (one
    simulation at twice the sub-steps), at the plan of that simulation.

    ``factor``: the :func:`~.budget.plan_factor` of a plan for the identified model's
    drive stage (:meth:`Problem.identification_work` binds :meth:`Problem.plan_factor`
    of the start)."""
    work = sum(spent for _, _, spent in segment_work(ident, data, factor))
    if ident.plan is None:
        return work
    fitted = [st for st in ident.steps if st.result is not None and st.recordings]
    last = int(np.size(fitted[-1].result.theta)) if fitted else 0
    columns = last if ident.uncertainty is not None else 0
    final = factor(ident.plan)
    return (work + evaluation_work(int(data.mask.size), columns, final)
            + evaluation_work(int(data.mask.size), 0, 2.0 * final))
