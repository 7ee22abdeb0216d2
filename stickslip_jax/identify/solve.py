"""One least-squares solve: Levenberg-Marquardt with progress and a verdict.

The Jacobian is built in forward mode, so its cost grows with the number of
parameters, not the length of the traces; it is the cost of every step (one value
and one Jacobian per LM step, nothing else touches the simulator).

:class:`ColumnSplitJacobian` evaluates it with its columns shared among threads:
each thread runs one vmapped forward-mode pass (the primal once, its share of the
tangents at once) of the same compiled program. The simulator's scan is sequential,
so XLA keeps one CPU core busy per call; two calls on two threads use two cores.

The step itself (:class:`LevenbergMarquardtSteps`) is optimistix's
``LevenbergMarquardt`` (a classical trust region over damped Gauss-Newton steps,
solved by QR) written out in numpy, on the value and Jacobian evaluated before it:
compiled, each solve's step was a program of its own for its shapes (about 0.5 s to
compile, four per identification, issue #28), for work of a few milliseconds.
"""

from __future__ import annotations

import dataclasses
import enum
import os
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np
from scipy.linalg import solve_triangular

from ..adjoint import value_and_jacfwd


class SolveStatus(enum.Enum):
    """How a solve ended (:attr:`SolveResult.status`); callers branch on it, the
    message is for people."""

    CONVERGED = "converged"
    """A convergence test passed (a stall within one standard error of the
    Gauss-Newton point included: the cost is rough there at the simulator's
    resolution)."""
    STEP_CAP = "step cap"
    """``max_steps`` steps taken without converging."""
    STALLED = "stalled"
    """No step lowers the cost, farther than a standard error from the optimum."""
    NON_FINITE = "non-finite"
    """The parameters or the cost left the finite numbers."""
    INTERRUPTED = "interrupted"
    """``stop_when`` ended it (:attr:`SolveResult.interrupted` says why)."""


@dataclass(frozen=True)
class SolveResult:
    """Outcome of one solve.

    ``theta`` the solution in fitted coordinates; ``status`` how it ended
    (:class:`SolveStatus`; ``converged`` is ``status is CONVERGED``); ``message`` the
    verdict in words; ``iterations`` the
    number of LM steps; ``wall_s`` [s] including compilation; ``cost_start`` and
    ``cost_end`` the sum of squared residuals at the start and the end;
    ``residual_start`` and ``residual`` the residual vectors there; ``jacobian`` the
    Jacobian d residual / d theta at the solution (the last accepted point), which
    the solver computed anyway. ``jacobians`` and ``values``: the evaluations it made,
    a residual with its Jacobian and a residual alone (by the ``value`` program), the
    work a budget charges. ``damping``: the Levenberg-Marquardt damping λ it would
    have taken the next step with (in its scaled coordinates). ``interrupted``: why
    ``stop_when`` ended it (empty when it did not).
    """

    theta: np.ndarray
    status: SolveStatus
    message: str
    iterations: int
    wall_s: float
    cost_start: float
    cost_end: float
    residual_start: np.ndarray | None = None
    residual: np.ndarray | None = None
    jacobian: np.ndarray | None = None
    jacobians: int = 0
    values: int = 0
    damping: float = float("nan")
    interrupted: str = ""

    @property
    def converged(self) -> bool:
        """Whether a convergence test passed."""
        return self.status is SolveStatus.CONVERGED


def jacobian_threads() -> int:
    """Threads that share a Jacobian's columns: ``STICKSLIP_JACOBIAN_THREADS`` if set,
    else the CPU cores (at most 4) on the CPU backend and 1 on an accelerator, whose
    one call already runs the columns in parallel."""
    env = os.environ.get("STICKSLIP_JACOBIAN_THREADS")
    if env:
        try:
            n = int(env)
        except ValueError:
            raise ValueError(f"STICKSLIP_JACOBIAN_THREADS must be a positive integer, "
                             f"got {env!r}") from None
        if n < 1:
            raise ValueError(f"STICKSLIP_JACOBIAN_THREADS must be a positive integer, got {n}")
        return n
    if jax.default_backend() != "cpu":
        return 1
    return max(1, min(os.cpu_count() or 1, 4))


_POOLS: dict[int, ThreadPoolExecutor] = {}


def jacobian_pool(threads: int) -> ThreadPoolExecutor:
    """The process's thread pool of ``threads`` workers for Jacobian columns (made once
    per size, kept: threads that compiled a program keep its caches warm)."""
    if threads not in _POOLS:
        _POOLS[threads] = ThreadPoolExecutor(max_workers=threads,
                                             thread_name_prefix="stickslip-jacobian")
    return _POOLS[threads]


class ColumnSplitJacobian:
    """``(fn(θ, args), ∂fn/∂θ)`` for a 1-D θ, the Jacobian's columns shared among
    ``threads`` (default :func:`jacobian_threads`).

    Each share is one vmapped forward-mode pass of the same compiled program (equal
    shares: the last is padded with zero tangents), so a solve compiles the simulator
    once. A pass's cost is mostly per-operation overhead, not arithmetic (measured
    through a 17-recording residual: one tangent 0.42 s, two vmapped 0.85 s, 22
    vmapped 1.15 s; 0.95, 2.63 and 4.34 s with an amplifier stage), so threads pay
    most for two columns (two one-tangent passes side by side) and for many.
    ``args`` are never differentiated.
    """

    def __init__(self, fn: Callable, threads: int | None = None):
        self.threads = jacobian_threads() if threads is None else int(threads)
        self._share = jax.jit(
            lambda theta, args, basis: value_and_jacfwd(lambda th: fn(th, args), theta, basis))
        self._programs: dict = {}

    def __call__(self, theta, args=None) -> tuple[jax.Array, jax.Array]:
        theta = jnp.asarray(theta, dtype=float)
        k = theta.size
        key = (k, jax.tree.structure(args))
        if key not in self._programs:
            # The shares' tangent bases and their program, compiled once here before any
            # thread starts (each thread would otherwise compile its own).
            w = max(1, min(self.threads, k))
            c = -(-k // w)
            bases = jnp.asarray(np.eye(w * c, k).reshape(w, c, k))
            self._programs[key] = (bases, self._share.lower(theta, args, bases[0]).compile())
        bases, share = self._programs[key]
        if len(bases) == 1:
            return share(theta, args, bases[0])
        futures = [jacobian_pool(len(bases)).submit(
            lambda b=b: jax.block_until_ready(share(theta, args, b))) for b in bases]
        parts = [f.result() for f in futures]
        return parts[0][0], jnp.concatenate([p[1] for p in parts], axis=1)[:, :k]


class LevenbergMarquardtSteps:
    """Levenberg-Marquardt one step at a time, as optimistix's ``LevenbergMarquardt``
    (``ClassicalTrustRegion`` and ``DampedNewtonDescent``) takes them, in numpy.

    Feed it the residual and Jacobian at :attr:`y_eval`, the point it tries
    (:meth:`step`); it accepts or rejects that point by the trust-region test (the
    cost fell by at least ``LOW_CUTOFF`` of the fall the linear model predicted; the
    first point is always accepted), scales the step size (1/λ) by ``HIGH_CONSTANT``
    after a step the model predicted to within ``HIGH_CUTOFF``, by ``LOW_CONSTANT``
    after a rejection, and proposes the next point: the least-squares solution of
    ``[J; √λ·I] δ = [r; 0]`` (QR) from the last accepted point, ``y − δ``. An accepted
    point also gets optimistix's Cauchy test (:attr:`terminate`): the change of y and
    of the residual since the last accepted point both below ``atol + rtol·|value|`` in
    RMS over their entries (never with ``rtol = atol = 0``).

    ``gauss_newton_trial``: after a step the linear model predicted to within
    ``HIGH_CUTOFF``, the next point tried is the full Gauss-Newton step's, ``y −
    J⁺r`` (directions with singular values below :data:`GAUSS_NEWTON_RCOND` of the
    largest left out), not the damped one: where the model holds, that point is the
    minimiser of the model, which a damping lowered 3.5x per step reaches only once λ
    is below JᵀJ's smallest eigenvalue (on an ill-conditioned linear fit, a drift's
    settling terms, several dozen steps). A rejected trial leaves λ as it was and the
    damped step is tried next (:func:`solve_least_squares` counts the two as one step);
    an accepted one updates λ as any step does. After a rejection the next trial waits
    until λ has fallen below where it was: the model failed at that reach.

    ``step_bounds``: ``y ↦ (lo, hi)``, the steps each coordinate's domain allows to first
    order (:meth:`~.parameters.ParameterMap.step_bounds`, in y's units). After an
    accepted point whose Gauss-Newton step leaves them, the next point tried is a
    *bound trial*, made from the least-squares step within them
    (:func:`bounded_gauss_newton_step`):

    - where that step puts no coordinate at a bound, the step itself (the Gauss-Newton
      point of the bounded model);
    - where it puts some at a bound, each of those is moved on until its part of the fit
      is negligible, and the others take λ's damped step on the residual with those at
      their bounds (undamped, a dozen correlated creep weights' trial failed by a
      factor 1e6). A coordinate whose first-order step to its bound alone lowers the
      cost by P_i moves ln(P_i / (``bound_tolerance``·σ̂²)) times that step (σ̂² =
      rᵀr/(N − p); at least once): a weight of log kind to the share
      ``bound_tolerance``·σ̂²/P_i of its value, and what its removal would still lower
      the cost by (P_i shrinks with the weight, to first order in proportion where
      the data pull it below 0) to ``bound_tolerance`` noise variances.

    A weight whose optimum is 0 lies at θ = −∞: the damped steps approach it ever more
    slowly (its column shrinks with it while λ does not: a viscous slope's sizing lost
    8 % of its distance to the optimum per step); the trial takes it there in one step,
    no deeper than the Gauss-Newton test needs (moved to a fixed 1e-3 of their values,
    weights went far deeper, and the next fit, the sizing with the baseline free, could
    not revive one: its column, and so the scale of that fit's coordinates, was as
    small, and every step overflowed). A trial is accepted by the same test, against
    the fall the bounded model predicted; a rejected one leaves λ as it was and the
    damped step is tried next (as a Gauss-Newton trial).
    """

    HIGH_CUTOFF = 0.99
    LOW_CUTOFF = 0.01
    HIGH_CONSTANT = 3.5
    LOW_CONSTANT = 0.25
    DAMPING_UPDATES = ("classical", "nielsen")
    """How an accepted step changes the damping λ (``damping_update``):

    - ``classical``: optimistix's ``ClassicalTrustRegion``: λ/3.5 after a step whose
      cost fell by at least ``HIGH_CUTOFF`` (99 %) of the linear model's prediction,
      unchanged otherwise;
    - ``nielsen``: Nielsen's continuous update (Madsen, Nielsen & Tingleff 2004, eq.
      3.16): λ·max(1/3, 1 − (2ρ − 1)³) with ρ the actual over the predicted fall, so λ
      falls (down to a third) after every step with ρ > 1/2 and rises (up to 2x)
      after a poor one. Along a curved valley, where no step meets the model to 1 %,
      the classical λ never falls and the steps creep.

    A rejected step raises λ 4x in both (``LOW_CONSTANT``)."""

    def __init__(self, y0, *, step_size: float = 1.0, rtol: float = 0.0, atol: float = 0.0,
                 damping_update: str = "classical", gauss_newton_trial: bool = False,
                 step_bounds: Callable[[np.ndarray], tuple] | None = None,
                 bound_tolerance: float = 0.01):
        if damping_update not in self.DAMPING_UPDATES:
            raise ValueError(f"damping_update must be one of {self.DAMPING_UPDATES}, "
                             f"got {damping_update!r}")
        self.damping_update = damping_update
        self.gauss_newton_trial = bool(gauss_newton_trial)
        self.trying_gauss_newton = False
        """Whether :attr:`y_eval` is a full Gauss-Newton point (``gauss_newton_trial``)."""
        self.trial_failed_at = 0.0
        """The step size (1/λ) when a trial was last rejected (0: none was)."""
        self.step_bounds = step_bounds
        self.bound_tolerance = float(bound_tolerance)
        self._bound_predicted = 0.0  # the bounded model's change of ½Σr² for that trial
        self.trying_bound = False
        """Whether :attr:`y_eval` is a bound trial (``step_bounds``)."""
        self.gain_ratio = np.nan
        """ρ of the point last decided: the cost's fall over the fall the linear model
        predicted (nan for the start)."""
        self.y = np.asarray(y0, dtype=float)
        self.y_eval = self.y.copy()
        self.step_size = float(step_size)
        self.rtol, self.atol = float(rtol), float(atol)
        self.residual = None
        self.jac = None
        self._triangle = None
        self.accepted = 0
        self.terminate = False
        self.predicted_fall = np.inf
        """The fall of ``Σ residual²`` the linear model predicted for the point last
        tried (inf for the start)."""

    def decide(self, value, reference_cost: float | None = None) -> tuple[bool, bool]:
        """``(accept, good)`` for the residual ``value`` (N,) at :attr:`y_eval` (the
        Jacobian is not needed to decide): accepted when the cost fell by at least
        ``LOW_CUTOFF`` of the fall the linear model predicted, good when by
        ``HIGH_CUTOFF`` of it. ``reference_cost``: the cost at the last accepted point
        as the program that computed ``value`` has it (default: ``Σ residual²`` of the
        accepted residual); sets :attr:`predicted_fall`."""
        value = np.asarray(value, dtype=float)
        if self.residual is None:
            return True, False
        rtr = float(np.sum(self.residual**2))
        reference = rtr if reference_cost is None else float(reference_cost)
        with np.errstate(over="ignore"):  # a point off the scale costs inf: rejected
            cost_diff = 0.5 * float(np.sum(value**2)) - 0.5 * reference
        if self.trying_bound:  # moved past the model's bound: the bounded step's fall
            predicted = self._bound_predicted
        else:
            predicted = 0.5 * (float(np.sum((self.jac @ (self.y_eval - self.y)
                                             + self.residual) ** 2)) - rtr)
        self.predicted_fall = -2.0 * predicted
        with np.errstate(divide="ignore", invalid="ignore"):
            self.gain_ratio = cost_diff / predicted if predicted < 0 else np.nan
        return (bool(cost_diff <= self.LOW_CUTOFF * predicted),
                bool(cost_diff < self.HIGH_CUTOFF * predicted and predicted < 0))

    def step(self, value, jac, decision: tuple[bool, bool] | None = None) -> bool:
        """Take the residual ``value`` (N,) and Jacobian ``jac`` (N, k) at
        :attr:`y_eval`; returns whether that point was accepted. ``decision``: what
        :meth:`decide` said of the point (from a value-only evaluation), else decided
        here; a rejected point needs no Jacobian (``jac`` None)."""
        value = np.asarray(value, dtype=float)
        accept, good = self.decide(value) if decision is None else decision
        if accept and self.residual is not None and not np.all(np.isfinite(jac)):
            # No step can be taken from a point whose derivatives the simulator could not
            # give (seen after a bound trial took a sensor delay towards 0): rejected.
            accept = good = False
        if not accept and self.trying_bound:
            pass  # λ's own step is untried: try it next, λ as it was
        elif not accept and self.trying_gauss_newton:
            # The undamped trial failed: λ's own step is untried, try it next.
            self.trial_failed_at = self.step_size
        elif not accept:
            self.step_size *= self.LOW_CONSTANT
        elif self.damping_update == "classical":
            self.step_size *= self.HIGH_CONSTANT if good else 1.0
        elif np.isfinite(self.gain_ratio):  # nielsen (the start has no ratio)
            self.step_size /= max(1.0 / 3.0, 1.0 - (2.0 * self.gain_ratio - 1.0) ** 3)
        if accept:
            residual = np.zeros_like(value) if self.residual is None else self.residual
            self.terminate = self._cauchy(self.y_eval - self.y, value, value - residual)
            self.y, self.residual, self.jac = self.y_eval, value, np.asarray(jac, dtype=float)
            self._triangle = None  # the new point's, made when a step first needs it
            self.accepted += 1
        else:
            self.terminate = False
        bound_step = self._bound_trial() if accept and self.step_bounds is not None else None
        self.trying_bound = bound_step is not None
        self.trying_gauss_newton = bool(self.gauss_newton_trial and accept and good
                                        and self.step_size > self.trial_failed_at
                                        and not self.trying_bound)
        if self.trying_bound:
            self.y_eval = self.y + bound_step
            return accept
        step = None
        if self.trying_gauss_newton:
            try:
                step = self._gauss_newton_step()
            except (np.linalg.LinAlgError, ValueError):  # the SVD failed: no trial here
                self.trying_gauss_newton = False
        if step is None:
            step = self._damped_step()
        self.y_eval = self.y + (-step)
        return accept

    @property
    def trying_trial(self) -> bool:
        """Whether :attr:`y_eval` is a trial (Gauss-Newton or bound) that, rejected, is
        followed at once by λ's damped step from the same point."""
        return self.trying_gauss_newton or self.trying_bound

    def _bound_trial(self) -> np.ndarray | None:
        """The bound trial's step from :attr:`y` (class docstring), or None where the
        Gauss-Newton step stays within the bounds or the bounded model's cost would not
        fall."""
        lo, hi = (np.asarray(b, dtype=float) for b in self.step_bounds(self.y))
        if not np.all(np.isfinite(self.jac)):
            return None
        try:
            return self._bounded_trial_step(lo, hi)
        except (np.linalg.LinAlgError, ValueError):  # no trial where the algebra fails
            return None

    def _bounded_trial_step(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
        gauss_newton = -self._gauss_newton_step()
        if np.all((gauss_newton >= lo) & (gauss_newton <= hi)):
            return None
        # Which coordinates the data put at their bounds: the undamped step's (a damped
        # step shortens a shrinking weight's move with its column, and never meets it).
        tri, c = self.triangle
        delta = bounded_gauss_newton_step(tri, c, lo, hi)
        with np.errstate(invalid="ignore"):  # (an infinite bound is never met)
            bound = np.where(delta <= lo + 1e-9 * np.abs(lo), lo,
                             np.where(delta >= hi - 1e-9 * np.abs(hi), hi, np.nan))
        met = np.isfinite(bound)
        if not met.any():
            # Within the bounds and off them: the Gauss-Newton point of the bounded model
            # (where the unbounded one, beyond a bound, is not worth a trial).
            self._bound_predicted = 0.5 * (float(np.sum((self.jac @ delta
                                                         + self.residual) ** 2))
                                           - float(np.sum(self.residual**2)))
            return delta if self._bound_predicted < 0 else None
        # The others take λ's damped step on the residual with those at their bounds (the
        # undamped one reaches far along directions the data barely see: a dozen
        # correlated creep weights' trial failed by a factor 1e6).
        at_bound = self.residual + self.jac[:, met] @ bound[met]
        free = ~met
        delta = np.zeros_like(delta)
        if free.any():
            # The same least squares in the triangle's rows: Qᵀ(r + J_m·b) = c + R_m·b.
            delta[free] = bounded_gauss_newton_step(tri[:, free], c + tri[:, met] @ bound[met],
                                                    -np.inf, np.inf, self._damping)
        rtr = float(np.sum(self.residual**2))
        model = at_bound + self.jac[:, free] @ delta[free]
        self._bound_predicted = 0.5 * (float(np.sum(model**2)) - rtr)
        if not self._bound_predicted < 0:
            return None
        sigma2 = rtr / max(self.residual.size - self.y.size, 1)
        moved = self.jac[:, met] * bound[met]  # each one's first-order move to its bound
        part = rtr - np.sum((self.residual[:, None] + moved) ** 2, axis=0)  # P_i
        with np.errstate(divide="ignore", invalid="ignore"):
            reach = np.log(part / (self.bound_tolerance * sigma2))
        delta[met] = bound[met] * np.where(reach > 1.0, reach, 1.0)
        return delta

    @property
    def triangle(self) -> tuple[np.ndarray, np.ndarray]:
        """``(R, c)``: the accepted point's Jacobian J = QR (R: k × k, upper triangular)
        and its residual in Q's columns, c = Qᵀr. Every step from the point solves a
        least-squares problem in J and r whose minimiser is the same in R and c
        (``|r + Jδ|² = |c + Rδ|² + |r|² − |c|²``), so the N-row factorisation is made
        once per accepted point, not once per step tried from it (most of a diagnosis's
        steps are rejected; a reduced diagnosis ran 4-7 % faster, benchmarks/README,
        ``experiments/bench_checkouts.py``)."""
        if self._triangle is None:
            self._triangle = triangle_of(self.jac, self.residual)
        return self._triangle

    def _gauss_newton_step(self) -> np.ndarray:
        # R's singular values are J's, so the same directions are left out.
        tri, c = self.triangle
        return np.linalg.lstsq(tri, c, rcond=GAUSS_NEWTON_RCOND)[0]

    @property
    def _damping(self) -> float:
        """λ, the damping of the next damped step (1/step size, capped)."""
        eps = np.finfo(float).eps
        return 1.0 / self.step_size if self.step_size > eps else np.finfo(float).max

    def _damped_step(self) -> np.ndarray:
        lm = self._damping
        tri, c = self.triangle
        k = tri.shape[1]
        a = np.concatenate([tri, np.sqrt(lm) * np.eye(k)])
        q, r = np.linalg.qr(a)
        return solve_triangular(r, q.T @ np.concatenate([c, np.zeros(k)]),
                                check_finite=False)

    def _cauchy(self, y_diff, f, f_diff) -> bool:
        def rms(x):
            return float(np.sqrt(np.mean(x**2)))

        with np.errstate(divide="ignore", invalid="ignore"):
            y_ok = rms(np.abs(y_diff) / (self.atol + self.rtol * np.abs(self.y_eval))) < 1
            f_ok = rms(np.abs(f_diff) / (self.atol + self.rtol * np.abs(f))) < 1
        return bool(y_ok and f_ok)


def triangle_of(jac: np.ndarray, residual: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R, Qᵀr)`` of the QR factorisation J = QR (``jac`` N × k, ``residual`` r (N,)),
    the rows where both are 0 left out first: they change neither (a padded recording's
    rows; up to half of a diagnosis's), and the factorisation's work is in proportion
    to the rows.

    Q is never formed: the triangle of the augmented [J r] is [[R, Qᵀr], [0, ρ]] (the
    Householder reflections of J's columns do not see a column after them), so one
    ``mode='r'`` factorisation gives both, 2-4x faster than forming the N × k Q and
    multiplying by it (the same R to 1e-16 and Qᵀr to 1e-14, relative)."""
    j = np.asarray(jac, dtype=float)
    r = np.asarray(residual, dtype=float)
    rows = np.flatnonzero(np.any(j != 0, axis=1) | (r != 0))
    if rows.size and rows.size < r.size:
        j, r = j[rows], r[rows]
    k = j.shape[1]
    m = min(j.shape[0], k)
    augmented = np.linalg.qr(np.column_stack([j, r]), mode="r")
    return augmented[:m, :k], augmented[:m, k]


GAUSS_NEWTON_RCOND = 1e-9
"""Singular values of the Jacobian below this share of the largest are directions the
data do not determine [-]: the Gauss-Newton step and its test leave them out."""


def gauss_newton_drop(residual, jac, *, rcond: float = GAUSS_NEWTON_RCOND,
                      bounds: tuple[np.ndarray, np.ndarray] | None = None,
                      triangle: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """What the full Gauss-Newton step from a point lowers the cost ``rᵀr`` by, to
    first order: with residual r (N,) and Jacobian J (N, p), δ = −(JᵀJ)⁺Jᵀr lowers it by
    Δ = gᵀ(JᵀJ)⁺g (g = Jᵀr). Directions whose singular value is below ``rcond`` times
    the largest (undetermined ones) are left out. [units of rᵀr]; infinite where no
    step can be measured: ``jac`` not finite, JᵀJ or Jᵀr overflowing, or eigenvalues
    that do not converge (a point the fit must not call converged; a caller that
    predicts from the drop treats it as no prediction).

    ``bounds``: ``(lo, hi)`` (p,), the steps the parameters' domains allow to first order
    (:meth:`~.parameters.ParameterMap.step_bounds`, in the coordinates of ``jac``). A
    step that leaves them is replaced by the least-squares step within them (bounded
    variable least squares on the QR of J): a weight whose optimum is its bound, 0,
    approaches it only as θ → −∞, and the unbounded step, which would carry it below
    0, promises a fall no step can give, however close the weight is (its drop does
    not shrink with the weight), so the fit never converged. Within the bounds the
    two steps are the same and so is the drop (the same arithmetic). ``triangle``: the
    point's ``(R, c)`` when already made (:attr:`LevenbergMarquardtSteps.triangle`), for
    JᵀJ = RᵀR, Jᵀr = Rᵀc and the bounded step's least squares (the same quantities to
    rounding, without another pass over the N rows)."""
    r = np.asarray(residual, dtype=float)
    j = np.asarray(jac, dtype=float)
    if not np.all(np.isfinite(j)):
        return np.inf
    with np.errstate(over="ignore", invalid="ignore"):
        # From the triangle where made: RᵀR = JᵀJ and Rᵀ(Qᵀr) = Jᵀr, in k rows, not N.
        h, g = ((triangle[0].T @ triangle[0], triangle[0].T @ triangle[1])
                if triangle is not None else (j.T @ j, j.T @ r))
    try:
        if not (np.all(np.isfinite(h)) and np.all(np.isfinite(g))):
            raise np.linalg.LinAlgError("JᵀJ or Jᵀr overflows")
        w, v = np.linalg.eigh(h)
    except np.linalg.LinAlgError:
        # A Jacobian so large its normal matrix overflows, or whose eigenvalues do not
        # converge: no step to measure, so no convergence is claimed.
        return np.inf
    keep = w > (rcond**2) * max(float(w[-1]), 1e-300)
    gv = v.T @ g
    drop = float(np.sum(gv[keep] ** 2 / w[keep]))
    if bounds is None:
        return drop
    lo, hi = (np.asarray(b, dtype=float) for b in bounds)
    step = -(v[:, keep] @ (gv[keep] / w[keep]))
    if np.all((step >= lo) & (step <= hi)):
        return drop
    try:
        return min(drop, _bounded_drop(j, r, lo, hi, triangle))
    except (np.linalg.LinAlgError, ValueError):  # the unbounded drop: no convergence claimed
        return drop


def bounded_gauss_newton_step(jac, residual, lo, hi, damping: float = 0.0) -> np.ndarray:
    """The step δ (p,) that minimises ``|r + Jδ|² + damping·|δ|²`` within ``lo ≤ δ ≤ hi``
    (bounded-variable least squares on the triangle of the QR of J, stacked on
    √damping·I for a damped step: the same minimum, p rows instead of N; the bounds
    widened to hold 0, the point itself)."""
    from scipy.optimize import lsq_linear

    jac = np.asarray(jac, dtype=float)
    residual = np.asarray(residual, dtype=float)
    if damping > 0:
        k = jac.shape[1]
        jac = np.concatenate([jac, np.sqrt(damping) * np.eye(k)])
        residual = np.concatenate([residual, np.zeros(k)])
    q, tri = np.linalg.qr(jac)
    c = q.T @ residual
    bounds = (np.minimum(lo, 0.0), np.maximum(hi, 0.0))
    return lsq_linear(tri, -c, bounds=bounds, method="bvls").x


def _bounded_drop(jac: np.ndarray, residual: np.ndarray, lo: np.ndarray,
                  hi: np.ndarray, triangle: tuple[np.ndarray, np.ndarray] | None = None
                  ) -> float:
    """``rᵀr − min |r + Jδ|²`` over lo ≤ δ ≤ hi (:func:`bounded_gauss_newton_step`, in
    ``triangle``'s ``(R, Qᵀr)`` when given: the same δ)."""
    delta = bounded_gauss_newton_step(*(triangle or (jac, residual)), lo, hi)
    return max(float(residual @ residual) - float(np.sum((jac @ delta + residual) ** 2)),
               0.0)


def gauss_newton_distance(residual, jac, *, rcond: float = GAUSS_NEWTON_RCOND,
                          bounds: tuple[np.ndarray, np.ndarray] | None = None,
                          triangle: tuple[np.ndarray, np.ndarray] | None = None) -> float:
    """Squared length of the full Gauss-Newton step from a point, in standard errors:
    its cost drop (:func:`gauss_newton_drop`, within ``bounds`` when given) divided by
    σ̂² = rᵀr/(N − p), the step's Mahalanobis length squared under the covariance
    σ̂²(JᵀJ)⁺. [-]; 0 at an exact fit (r = 0), infinite where the residual or the
    Jacobian is not finite (no convergence is claimed where no step can be measured).
    """
    r = np.asarray(residual, dtype=float)
    n, p = np.shape(jac)
    sigma2 = float(r @ r) / max(n - p, 1)
    if not (np.isfinite(sigma2) and np.all(np.isfinite(jac))):
        return float("inf")
    if sigma2 <= 0:
        return 0.0
    return gauss_newton_drop(r, jac, rcond=rcond, bounds=bounds, triangle=triangle) / sigma2


def value_and_jacobian(residuals: Callable, theta):
    """``(residuals(θ), ∂residuals/∂θ)`` from forward mode, shared among threads
    (numpy arrays)."""
    value, jac = ColumnSplitJacobian(lambda th, args: residuals(th))(theta)
    return np.asarray(value), np.asarray(jac)


STALL_REJECTIONS = 5
"""Consecutive rejected Levenberg-Marquardt steps, each promised by the linear model a
fall of ``Σ residual²`` below one noise variance σ̂² = cost/(N − p), after which a fit
under the Gauss-Newton test (``gn_tol``) stops as stalled (a rejected step that promised
more, far from the optimum, is ordinary trust-region work and resets the count). Each
rejection shortens the next step, so the fifth tries a much shorter one. Converged when the
Gauss-Newton step from the point is within one standard error (its quadratic model
then puts the cost within one noise variance σ̂² of its minimum), not converged
otherwise."""


@dataclass(frozen=True)
class LMSettings:
    """How one Levenberg-Marquardt solve runs and when it stops (every field is
    explained at :func:`solve_least_squares`): ``max_steps``; the Cauchy tolerances
    ``rtol``, ``atol``; the stationary-cost test ``ftol`` (None: 0.1/N) over ``window``
    accepted steps; the Gauss-Newton point test ``gn_tol`` [SE²] (None: off; set, it
    replaces the other tests); ``initial_damping``; ``scale_by_jacobian``;
    ``damping_update`` (:attr:`LevenbergMarquardtSteps.DAMPING_UPDATES`);
    ``gauss_newton_trial`` (:class:`LevenbergMarquardtSteps`)."""

    max_steps: int = 60
    rtol: float = 1e-4
    atol: float = 1e-6
    ftol: float | None = None
    window: int = 5
    gn_tol: float | None = None
    initial_damping: float = 1.0
    scale_by_jacobian: bool = True
    damping_update: str = "classical"
    gauss_newton_trial: bool = False

    def replace(self, **changes) -> LMSettings:
        """These settings with ``changes`` (field names; TypeError on an unknown one)."""
        return dataclasses.replace(self, **changes)


def solve_least_squares(residuals, theta0, settings: LMSettings | None = None, *,
                        label: str = "fit", echo: Callable[[str], None] | None = None,
                        jacobian: Callable | None = None, value: Callable | None = None,
                        stop_when: Callable[[np.ndarray], str] | None = None,
                        step_bounds: Callable[[np.ndarray], tuple] | None = None,
                        **changes) -> SolveResult:
    """Minimise ``Σ residuals(θ)²`` from ``theta0`` with Levenberg-Marquardt, run as
    ``settings`` (:class:`LMSettings`; default ``LMSettings()``) with ``changes`` to
    its fields given as keywords (``max_steps=15``).

    :class:`LevenbergMarquardtSteps` (optimistix's solver, in numpy) takes the steps;
    this loop drives them one at a time so that it can report progress and apply a
    second convergence test, and evaluates the residual and its Jacobian at the point
    each step tries before the step (:class:`ColumnSplitJacobian`, the one place the
    simulator runs). Two ways to converge, whichever comes first:

    - optimistix's Cauchy test: the change of θ and of the residual vector between
      accepted steps are small in RMS over their entries, ``rms(|Δθ| / (atol +
      rtol·|θ|)) < 1`` and the same for the residuals. θ is a relative change of each
      parameter, so ``atol = 1e-6`` is 1 ppm.
    - a stationary cost (MINPACK's ftol test): over the last ``window`` accepted steps
      the cost fell by less than ``ftol`` of itself. Near the optimum of N residuals
      moving the parameters by one standard error changes the cost by about cost/N,
      so the default ``ftol = 0.1/N`` stops once the steps move the fit by well under
      a standard error; this ends fits whose poorly determined directions (e.g. a PI
      weight) keep drifting without effect, which the θ test alone would hold open.

    Both tests look at the steps taken, so along a poorly conditioned direction, where
    LM creeps, they can pass far from the optimum: on the identification fixtures they
    stopped the joint fit with Mp, Dp and Kp 3 standard errors from where the cost is
    least. ``gn_tol`` replaces them with a test of the point itself
    (:func:`gauss_newton_distance`): converged when the full Gauss-Newton step from
    the accepted point is shorter than ``sqrt(gn_tol)`` standard errors, measured in
    the metric JᵀJ/σ̂² (σ̂² = cost/(N − p)); ``gn_tol = 0.01`` is a tenth of a standard
    error in every direction the data determine. Then the Cauchy and ftol tests are
    off, and a fit that gets no closer ends at ``max_steps``, not converged, or earlier
    when :data:`STALL_REJECTIONS` steps in a row that promised less than one noise
    variance are rejected (converged when the
    Gauss-Newton step is within one standard error: the cost is rough there at the
    simulator's resolution).

    ``initial_damping``: the LM damping λ at the start, in the scaled coordinates
    (where every column of the Jacobian has norm 1, so λ is relative to the largest
    diagonal of JᵀJ). Optimistix starts at 1 and lowers it 3.5x per step whose
    quadratic model predicted the cost to 1 %: from a start near the optimum, along
    strongly correlated directions (the PI weights), that is ~8 damped steps, each a
    Jacobian, before the steps become Gauss-Newton's. Madsen, Nielsen & Tingleff
    (2004, §3.2) start at 1e-6 when the start is believed to be close to the
    minimiser, at 1e-3 (or 1) otherwise (a rejected step raises it 4x at the cost of
    one evaluation).

    ``scale_by_jacobian`` (MINPACK's and scipy's ``x_scale='jac'``): the solve runs in
    φ = d·(θ − θ0) with d the column norms of the Jacobian at the start, so every
    direction has unit sensitivity and the LM damping (λ = 1 at the start) is on the
    scale of JᵀJ from the first step. Without it a well-scaled residual (cost ~1e-5)
    starts with a damping thousands of times too strong and creeps for ~10 steps. The
    Cauchy tolerances then apply to φ: atol = 1e-6 is a change worth 1e-6 of one
    unit-sensitivity direction.

    ``jacobian``: ``θ ↦ (residuals(θ), ∂residuals/∂θ)`` evaluated elsewhere (the
    identification's shared programs, :class:`~.sensitivities.StepJacobian`) instead
    of :class:`ColumnSplitJacobian` over ``residuals``. ``value``: with it,
    ``θ ↦ residuals(θ)`` alone (a value-only program, a fraction of a Jacobian's work):
    each point a step tries is then evaluated by ``value`` first and accepted or
    rejected on that, and only an accepted point gets its Jacobian. A rejected point
    (five in a row end a stalled fit; a start far from the optimum may take a dozen)
    then costs a simulation instead of a Jacobian. The acceptance test compares costs
    of one program: the start's and each accepted point's are evaluated by ``value``
    too.

    ``damping_update``: how an accepted step changes the damping
    (:attr:`LevenbergMarquardtSteps.DAMPING_UPDATES`). ``gauss_newton_trial``: after a
    step the linear model predicted well, try the full Gauss-Newton point next
    (:class:`LevenbergMarquardtSteps`).

    ``step_bounds``: ``θ ↦ (lo, hi)``, the steps δθ each parameter's domain allows to
    first order (:meth:`~.parameters.ParameterMap.step_bounds`); the Gauss-Newton test
    then measures the step within them (:func:`gauss_newton_drop`), so that a fit whose
    optimum puts a weight at its bound (an entry's form with no part there) converges.

    ``stop_when``: ``θ ↦ reason``, asked at each accepted point after the start; a
    non-empty reason ends the solve there, not converged, with the reason in
    ``interrupted`` and the damping to go on with in ``damping`` (the caller changes
    what it evaluates with and continues from ``theta``: the identification re-plans
    its sub-steps, :func:`~.steps.identify`).

    Never raises on failure: the verdict is in the result.
    """
    settings = (settings or LMSettings()).replace(**changes)
    max_steps, rtol, atol, ftol = (settings.max_steps, settings.rtol, settings.atol,
                                   settings.ftol)
    window, gn_tol, initial_damping = settings.window, settings.gn_tol, settings.initial_damping
    scale_by_jacobian, damping_update = settings.scale_by_jacobian, settings.damping_update
    value_of, value = value, None  # (``value`` below: the residual at a point)
    theta0 = jnp.asarray(theta0, dtype=float)
    start = time.perf_counter()
    if theta0.size == 0:
        r = np.asarray(residuals(theta0))
        cost = float(np.sum(r**2))
        return SolveResult(np.asarray(theta0), SolveStatus.CONVERGED,
                           "converged (nothing free)", 0,
                           time.perf_counter() - start, cost, cost, r, r,
                           np.zeros((r.size, 0)), jacobians=0, values=1)

    # The solve runs in φ = d·(θ − θ0); d and θ0 are arguments of the compiled
    # Jacobian, so the scaling is chosen after the first evaluation without compiling
    # again.
    def scaled(phi, args):
        origin, d = args
        return residuals(origin + phi / d)

    counts = {"jacobians": 0, "values": 0}  # the evaluations made (SolveResult)
    if jacobian is None:
        evaluate_at = ColumnSplitJacobian(scaled)
    else:
        def evaluate_at(phi, args):
            origin, d = (np.asarray(a) for a in args)
            value, jac = jacobian(origin + np.asarray(phi) / d)
            return np.asarray(value), np.asarray(jac) / d[None, :]

    def evaluate(phi, args):
        counts["jacobians"] += 1
        return evaluate_at(phi, args)

    phi0 = np.zeros(theta0.shape)
    d = np.ones(theta0.shape)
    value, jac = evaluate(phi0, (theta0, d))
    if scale_by_jacobian:
        # MINPACK's x_scale='jac': the Jacobian at the start gives the column norms,
        # and the solve runs in the scaled coordinates (∂r/∂φ = ∂r/∂θ / d).
        j = np.asarray(jac)
        with np.errstate(over="ignore"):
            norms = np.sqrt(np.sum(j**2, axis=0))
        big = ~np.isfinite(norms) & np.all(np.isfinite(j), axis=0)
        if big.any():  # a finite column whose squares overflow: its norm scaled down first
            top = np.max(np.abs(j[:, big]), axis=0)
            norms[big] = top * np.sqrt(np.sum((j[:, big] / top) ** 2, axis=0))
        largest = float(norms.max())
        norms = np.where(np.isfinite(norms) & (norms > 1e-12 * max(largest, 1e-300)), norms,
                         max(largest, 1.0))
        d = norms
        jac = np.asarray(jac) / d[None, :]
    if ftol is None:
        ftol = 0.1 / max(int(np.size(value)), 1)
    if gn_tol is not None:
        # Only the point test decides (the Cauchy test never passes at 0).
        rtol = atol = ftol = 0.0
    bounds_at = None
    if step_bounds is not None:
        def bounds_at(phi):  # θ = θ0 + φ/d: a step δφ = d·δθ
            lo, hi = step_bounds(np.asarray(theta0) + np.asarray(phi) / d)
            return d * np.asarray(lo), d * np.asarray(hi)
    lm = LevenbergMarquardtSteps(phi0, step_size=1.0 / initial_damping, rtol=rtol, atol=atol,
                                 damping_update=damping_update,
                                 gauss_newton_trial=settings.gauss_newton_trial,
                                 step_bounds=bounds_at,
                                 bound_tolerance=gn_tol if gn_tol is not None else 0.01)
    costs: list[float] = []  # cost at each accepted point, the start first
    residual_start = None
    jac_accepted = jac  # the Jacobian (in φ) at the last accepted point
    status, message, n = SolveStatus.STEP_CAP, f"not converged: hit max_steps={max_steps}", 0
    distance = np.inf  # the Gauss-Newton test's at the last accepted point [SE²]
    rejected_run = 0  # consecutive rejected steps
    interrupted = ""

    def value_cost(phi) -> tuple[float, np.ndarray]:  # by the value-only program
        counts["values"] += 1
        r = np.asarray(value_of(np.asarray(theta0) + np.asarray(phi) / d))
        with np.errstate(over="ignore"):  # a point off the scale costs inf (rejected)
            return float(np.sum(r**2)), r

    reference_cost = value_cost(phi0)[0] if value_of is not None else None
    # The first step only takes the start (always accepted); each later one tries the
    # point the one before proposed, and accepts or rejects it.
    def take(n: int) -> bool:  # evaluate the point step n tries; accept or reject it
        nonlocal value, jac, reference_cost
        decision = trial_cost = None
        if n and value_of is not None:  # the point this step tries, its value first
            trial_cost, trial = value_cost(lm.y_eval)
            decision = lm.decide(trial, reference_cost)
            if decision[0]:
                value, jac = evaluate(lm.y_eval, (theta0, d))
            else:
                value, jac = trial, None
        elif n:  # the point this step tries (the start's was evaluated above)
            value, jac = evaluate(lm.y_eval, (theta0, d))
        accepted = lm.step(value, jac, decision)
        if accepted and trial_cost is not None:
            reference_cost = trial_cost
        return accepted

    for n in range(max_steps + 1):
        trial_point = lm.trying_trial
        accepted_now = take(n)
        if trial_point and not accepted_now:
            # A rejected trial (Gauss-Newton or bound) is not one of the steps: the damped
            # point it stood in for is tried at once, so where every trial fails the fit takes
            # the damped steps alone, the same path (an evaluation more per trial).
            accepted_now = take(n)
        if accepted_now:
            jac_accepted, rejected_run = jac, 0
        elif lm.predicted_fall <= np.sum(lm.residual**2) / max(lm.residual.size - phi0.size, 1):
            # Rejected where the model promised less than one noise variance σ̂²: the
            # cost's roughness at the simulator's resolution, not a far-off optimum.
            rejected_run += 1
        else:
            rejected_run = 0
        cost = float(np.sum(lm.residual**2))
        if lm.accepted > len(costs):
            costs.append(cost)
            if gn_tol is not None:  # (value, jac) are this accepted point's
                bounds = None if bounds_at is None else bounds_at(lm.y)
                distance = gauss_newton_distance(value, jac, bounds=bounds,
                                                 triangle=lm.triangle)
                if echo is not None:
                    echo(f"  {label}: Gauss-Newton step {np.sqrt(distance):.3g} SE")
                if distance <= gn_tol:
                    status = SolveStatus.CONVERGED
                    message = (f"converged (the Gauss-Newton step is "
                               f"{np.sqrt(distance):.2g} standard errors)")
                    break
        if residual_start is None:
            residual_start = lm.residual
        if echo is not None:
            echo(f"  {label}: step {n:3d}  accepted {lm.accepted - 1:3d}  cost {cost:.4e}")
        if not (np.all(np.isfinite(lm.y)) and np.isfinite(cost)):
            status, message = SolveStatus.NON_FINITE, "failed: non-finite parameters or cost"
            break
        if lm.terminate:
            status = SolveStatus.CONVERGED
            message = "converged (parameter and residual changes below tolerance)"
            break
        if gn_tol is not None and rejected_run >= STALL_REJECTIONS:
            # The quadratic model promises a fall smaller than one noise variance, and
            # no step delivers it, each 4x shorter than the one before: the cost is
            # rough at this scale (a simulated stick-slip event moves a sample). Within
            # a standard error that is the optimum as far as the simulator resolves it.
            ok = distance <= 1.0
            status = SolveStatus.CONVERGED if ok else SolveStatus.STALLED
            message = (f"{'converged' if ok else 'not converged'} (stalled: no step lowers "
                       f"the cost, {STALL_REJECTIONS} rejected in a row; the Gauss-Newton "
                       f"step is {np.sqrt(distance):.2g} standard errors)")
            break
        if (gn_tol is None and len(costs) > window
                and costs[-window - 1] - costs[-1] <= ftol * costs[-1]):
            status = SolveStatus.CONVERGED
            message = (f"converged (cost stationary: fell by less than {ftol:.2g} "
                       f"of itself over {window} accepted steps)")
            break
        # Last: a point that converged ends the solve as converged.
        if stop_when is not None and n and accepted_now:
            interrupted = stop_when(np.asarray(theta0) + lm.y / np.asarray(d))
            if interrupted:
                status, message = SolveStatus.INTERRUPTED, f"interrupted: {interrupted}"
                break
    # The last accepted point, its residual, and the Jacobian evaluated with it.
    residual = lm.residual
    jac = np.asarray(jac_accepted) * np.asarray(d)[None, :]
    wall = time.perf_counter() - start
    cost_start, cost_end = (costs[0], costs[-1]) if costs else (np.nan, np.nan)
    theta = np.asarray(theta0) + lm.y / np.asarray(d)
    return SolveResult(theta, status, message, n, wall, cost_start, cost_end, residual_start,
                       residual, jac, **counts, damping=1.0 / lm.step_size,
                       interrupted=interrupted)
