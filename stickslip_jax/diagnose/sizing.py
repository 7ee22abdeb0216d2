"""Sizing: which scored entries are sized, and the sizing itself.

An entry is sized with the baseline held: its own 1-3 parameters fitted
(:attr:`~.config.DiagnoseConfig.size_steps` steps at most), cheap. It starts from the
Gauss-Newton step of the score test, the entry at its strength and the baseline moved by
its share of the step (the best of 1, 1/2, 1/4, 1/8 of it; :func:`first_order_start`);
an entry with seeds whose first-order sign is wrong starts from its cheapest seed
(:func:`best_seed`). In round one it is sized on the baseline before its polish too, and
the better sizing is kept (:func:`size_best`), when the polish moved the baseline:
:func:`~.run.diagnose` passes the polished baseline as ``unpolished`` (no second sizing)
when the polish removed no material part of the identified baseline's cost (within the
tolerance, :mod:`~stickslip_jax.significance`), as after an identification whose joint
step already minimised the whitened residual; the two are then one baseline to the data,
and a second sizing from it would differ only by its cruder start. What the sizing
removed, ``size_drop``, ranks the refits with the score (:func:`~.rules.rank_value`).

The sized entry is then fitted once more with the baseline free *to first order*
(:func:`size_with_baseline_free`): its own parameters fitted to the residual less its
part in the span of the baseline's Jacobian (variable projection,
:class:`~.problem.ProjectedResiduals`). The score test takes the baseline's response
to first order and the entry's to first order; the sizing takes the entry's in full
and the baseline's not at all; this takes both: the entry in full, the baseline to
first order, what a refit (every parameter free) buys when the baseline moves little.
An entry whose effect the baseline absorbed while it was identified can only show its
strength this way: a 0.5 µs amplifier lag, half absorbed, removed 10 % of the excess
with the baseline held and all of it once refitted, while an output delay, which the
baseline cannot absorb, removed 87 % held; ranked by the held drop, the amplifier
never got a refit.

The first order holds only near the baseline. Where the free sizing stops, the move
the baseline makes to first order is measured
(:meth:`~.problem.BaselineSpan.reach`); beyond a factor e in any of its coordinates
(:data:`~.problem.FIRST_ORDER_REACH`, the cap :func:`first_order_start` puts on the
score's shift) the sizing is *extrapolated*: the linearised baseline "restores" what
the entry destroyed (a drive lag long enough to flatten the trace, put back by PI
weights scaled up in proportion), a fall no refit can have. Its drop is then not
counted (:func:`record_free_sizing`). Seen on the reduced test protocol: a drive
low-pass whose free sizing fell by 44 000 at a move of 1.12 while its refit removed
nothing; the free sizings that a refit confirmed moved the baseline by 0.0001-0.65.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ..identify.parameters import ParameterMap
from ..model.actuator import Actuator
from .catalogue import Candidate, Probe
from .policy import DEFAULT_POLICY, Policy
from .problem import FIRST_ORDER_REACH, BaselineSpan, FitProgram, Problem, largest_move
from .results import CandidateResult, CandidateStatus


def first_order_start(problem: Problem, act: Actuator, base_names: list[str],
                      cand: Candidate, strength: float, probe: Probe, shift: np.ndarray):
    """The entry attached at a fraction of its Gauss-Newton strength, with the baseline
    moved by the same fraction of its share of the step: the fraction (1, 1/2, 1/4, 1/8)
    and the entry's option there (:meth:`~.catalogue.CatalogueEntry.attach_options`)
    whose start costs least (the linearised step overshoots for large effects)."""
    pmap = ParameterMap.make(act, base_names)
    # A linearised shift beyond a factor e of any baseline quantity (θ is logarithmic
    # for them) is extrapolation, not a first-order move: cap it.
    shift = np.clip(shift, -FIRST_ORDER_REACH, FIRST_ORDER_REACH)
    best = None
    for frac in (1.0, 0.5, 0.25, 0.125):
        moved = pmap.actuator(jnp.asarray(frac * shift))
        try:
            options = cand.attach_options(moved, frac * strength, probe)
        except ValueError:  # e.g. the moved PI loop folded (a partial sum below zero)
            continue
        for start, specs in options:
            try:
                ParameterMap.make(start, base_names)  # the refit must be able to start here
                cost = problem.evaluate(start)[0]
            except ValueError:
                continue
            if np.isfinite(cost) and (best is None or cost < best[0]):
                best = (cost, start, specs)
    if best is None:
        start, specs = cand.attach(act, 0.25 * strength, probe)
        return start, specs
    return best[1], best[2]


def best_seed(problem: Problem, act: Actuator, base_names: list[str], cand: Candidate):
    """``(cost, start, specs)`` of the entry's cheapest seed on ``act``, or None."""
    best = None
    for start, specs in cand.seeds(act):
        try:
            ParameterMap.make(start, base_names)
            cost = problem.evaluate(start)[0]
        except ValueError:
            continue
        if np.isfinite(cost) and (best is None or cost < best[0]):
            best = (cost, start, specs)
    return best


@dataclass(frozen=True)
class HeldSizing:
    """An entry sized with the baseline held (:func:`size_best`): where its refits
    start (:func:`~.refit.refit_start`), and the program and θ its sizing with the
    baseline free to first order goes on from (:func:`size_with_baseline_free`)."""

    start: Actuator
    """The sized actuator: the baseline it was sized on, with the entry at its sized
    values."""
    specs: dict
    """The entry's own quantities (``name →`` :class:`~stickslip_jax.identify.
    parameters.ParameterSpec`)."""
    program: FitProgram
    """The sizing's compiled program (its coordinates)."""
    theta: np.ndarray
    """Where the sizing stopped, in those coordinates."""
    cost: float
    """Its whitened cost there."""
    converged: bool
    """It ended by its Gauss-Newton test, not at its step cap."""


def size_best(problem: Problem, name: str, starts, *, max_steps: int) -> HeldSizing | None:
    """Size an entry from each ``(tag, start, specs)`` of ``starts`` (its own parameters,
    the baseline held, ``max_steps`` steps at most: :attr:`~.config.DiagnoseConfig.
    size_steps`): the lowest (:class:`HeldSizing`), or None."""
    best = None
    for tag, start, specs in starts:
        label = f"size {name} ({tag})" if tag else f"size {name}"
        program = problem.program(start, list(specs), specs)
        sized, cost, out = problem.fit_from(program, program.pmap.zeros(), label=label,
                                            max_steps=max_steps)
        if best is None or cost < best.cost:
            best = HeldSizing(sized, specs, program, np.asarray(out.theta), float(cost),
                              bool(out.converged))
    return best


@dataclass(frozen=True)
class FreeSizing:
    """An entry's sizing with the baseline free to first order
    (:func:`size_with_baseline_free`), where it stopped: enough to carry it on."""

    name: str
    program: FitProgram
    """The held sizing's compiled program (its coordinates)."""
    theta: np.ndarray
    """Where the fit stopped, in those coordinates."""
    span: BaselineSpan
    """The span of the baseline's Jacobian taken out of the residual."""
    cost: float
    """Its whitened cost there (projected)."""
    converged: bool
    """It ended by its Gauss-Newton test."""
    move: np.ndarray
    """The baseline's first-order move [θ] its cost takes for granted
    (:meth:`~.problem.BaselineSpan.move` of the residual where it stopped)."""

    @property
    def reach(self) -> float:
        """The largest |move| of a baseline coordinate [θ]
        (:meth:`~.problem.BaselineSpan.reach`)."""
        return largest_move(self.move)

    @property
    def extrapolated(self) -> bool:
        """It stopped where the baseline's first-order move passes
        :data:`~.problem.FIRST_ORDER_REACH`: its cost is the linearisation's, not one a
        refit can reach."""
        return self.reach > FIRST_ORDER_REACH

    def point(self, base_names: Sequence[str]) -> Actuator:
        """The model its cost stands for: the entry at the sizing's values on the
        baseline moved by :attr:`move` (from the baseline the entry was sized on). A
        ValueError where the move leaves the baseline's domain (a PI loop folded)."""
        sized = self.program.pmap.actuator(np.asarray(self.theta), xp=np)
        return ParameterMap.make(sized, list(base_names)).actuator(np.asarray(self.move),
                                                                   xp=np)

    def carried_on(self, problem: Problem, max_steps: int) -> FreeSizing:
        """The same fit carried on from where it stopped, at most ``max_steps`` more
        steps (:attr:`~.config.DiagnoseConfig.carry_on_steps`; no compile: the same
        program)."""
        return size_with_baseline_free(problem, self.name, self.program, self.theta,
                                       self.span, max_steps=max_steps,
                                       tag="baseline free to first order, carried on")


def size_with_baseline_free(problem: Problem, name: str, program: FitProgram, theta,
                            baseline_span: BaselineSpan, *, max_steps: int,
                            tag: str = "baseline free to first order") -> FreeSizing:
    """The sized entry's own parameters (``program``'s, from ``theta``, where the held
    sizing ended) fitted to the residual less its part in ``baseline_span``
    (the span of the baseline's Jacobian at the round's start): its cost is the cost
    with the baseline free to first order (module docstring). It goes on in the held
    sizing's coordinates with its compiled program. Where it stops, the baseline's
    first-order move is measured (one simulation); beyond
    :data:`~.problem.FIRST_ORDER_REACH` it is said."""
    label = f"size {name} ({tag})"
    _, cost, out = problem.fit_from(program, theta, max_steps=max_steps, label=label,
                                    project=baseline_span.basis)
    theta = np.asarray(out.theta)
    free = FreeSizing(name, program, theta, baseline_span, float(cost),
                      bool(out.converged),
                      baseline_span.move(problem.residual_at(program, theta)))
    verdict = ("extrapolated, its drop not counted" if free.extrapolated
               else "within the first order")
    problem.say(f"[{label}] the baseline's first-order move reaches {free.reach:.3g} (θ; "
                f"trusted up to {FIRST_ORDER_REACH:g}, a factor e): {verdict}")
    return free


def record_free_sizing(res: CandidateResult, free: FreeSizing, rss: float) -> None:
    """Set ``res``'s drop with the baseline free to first order from ``free`` (``rss``:
    the round's start; never below the held drop nor below an earlier free drop) and
    whether that sizing converged. An :attr:`~FreeSizing.extrapolated` one counts
    for nothing beyond the held drop and bounds nothing
    (:func:`~.rules.refit_reach`); it is not carried on (:func:`~.rules.unbounded`)."""
    if free.extrapolated:
        drop, converged = res.size_drop, False
    else:
        drop = max(rss - free.cost, res.size_drop_free, res.size_drop)
        converged = free.converged
    res.sizing = dataclasses.replace(res.sizing, free_reach=free.reach, drop_free=drop,
                                     free_converged=converged)


def carry_on_free_sizing(problem: Problem, res: CandidateResult,
                         free_sizings: dict[str, FreeSizing], rss: float, *,
                         max_steps: int) -> None:
    """Carry ``res``'s free sizing (in ``free_sizings``, replaced there) on by at most
    ``max_steps`` steps (:meth:`FreeSizing.carried_on`) and record it
    (:func:`record_free_sizing`): a sizing that stopped short of its optimum bounds
    nothing (:func:`~.rules.refit_reach`)."""
    free = free_sizings[res.name] = free_sizings[res.name].carried_on(problem, max_steps)
    record_free_sizing(res, free, rss)


def worth_sizing_after_acceptance(chosen: list[CandidateResult], excess: float,
                                  policy: Policy = DEFAULT_POLICY) -> list[CandidateResult]:
    """Entries of ``chosen`` whose |score| reaches :attr:`~.Policy.later_score_share` of
    ``excess`` (the (e/σ)² over the noise left by the accepted entries); the others
    are set aside with a note saying why they were not sized."""
    floor = policy.later_score_share * max(excess, 0.0)
    for r in chosen:
        if abs(r.score) < floor:
            r.set_aside(CandidateStatus.NOT_SIZED,
                        f"not sized: |score| {abs(r.score):.3g} below "
                        f"{100 * policy.later_score_share:.0f} % of the excess left "
                        f"({excess:.3g})")
    return [r for r in chosen if abs(r.score) >= floor]


def chosen_for_sizing(results: list[CandidateResult], seeded: set[str], size_at_most: int,
                      excess_left: float | None, say: Callable[[str], None],
                      policy: Policy = DEFAULT_POLICY) -> list[CandidateResult]:
    """The entries of ``results`` to size: admissible signs first, then by |score|, the
    first ``size_at_most``; and every entry with seeds (``seeded``: names), whose cost
    is rugged in a nonlinear parameter, so that a score taken at zero effect says little
    about an effect at a distance. After an acceptance (``excess_left``: the (e/σ)²
    over the noise the accepted entries left; None in round one) only those
    :func:`worth_sizing_after_acceptance`. Entries below :attr:`~.Policy.score_min` are
    chosen but not sized (:func:`size_entries`)."""
    order = sorted(results, key=lambda r: (r.score < 0, -abs(r.score)))
    chosen = order[:size_at_most] + [r for r in order[size_at_most:] if r.name in seeded]
    if excess_left is not None:
        chosen = worth_sizing_after_acceptance(chosen, excess_left, policy)
        if not chosen:
            say(f"[score] no entry scores {100 * policy.later_score_share:.0f} % of the "
                f"excess the accepted entries left ({excess_left:.3g}): stop")
    return chosen


def size_entries(problem: Problem, chosen: Sequence[CandidateResult],
                 pool: Sequence[Candidate], scores: dict, act: Actuator,
                 unpolished: Actuator, rss: float, base_names: list[str],
                 seeded: set[str], *, round_one: bool, max_steps: int,
                 policy: Policy = DEFAULT_POLICY,
                 baseline_span: BaselineSpan | None = None,
                 free_sizings: dict[str, FreeSizing] | None = None,
                 ) -> dict[str, HeldSizing]:
    """Size each entry of ``chosen`` whose |score| reaches :attr:`~.Policy.score_min`,
    (``max_steps`` steps at most each) from the round's optimum ``act`` (cost ``rss``)
    and, in round one, from
    ``unpolished`` too (the polish can bend the baseline to mimic part of an effect, a
    local optimum the joint refit may not leave); the better sizing is kept. Sets each
    sized entry's ``size_drop`` and status, and, given ``baseline_span`` (the
    span of the baseline's Jacobian at ``act``), its ``size_drop_free``
    (:func:`size_with_baseline_free`; never below ``size_drop``), kept in
    ``free_sizings`` (``name →`` :class:`FreeSizing`) when given; returns ``name →``
    :class:`HeldSizing` (``scores``: :func:`~.scores.score_candidates`'s)."""
    sized = {}
    for res in chosen:
        if abs(res.score) < policy.score_min:
            continue
        cand = next(c for c in pool if c.name == res.name)
        _, strength, probe, shift = scores[res.name]
        before_polish = round_one and unpolished is not act
        if res.name in seeded and res.score < 0:
            # The linearisation points the wrong way: start from the cheapest seed.
            bases = [(act, "seed")] + ([(unpolished, "seed, unpolished")]
                                       if before_polish else [])
            starts = [(tag, *seeded_start[1:]) for on, tag in bases
                      if (seeded_start := best_seed(problem, on, base_names, cand))]
        else:
            starts = [("", *first_order_start(problem, act, base_names, cand,
                                              strength, probe, shift))]
            if before_polish:
                starts.append(("unpolished",
                               *cand.attach(unpolished, 0.25 * strength, probe)))
        held = size_best(problem, cand.name, starts, max_steps=max_steps)
        if held is None:
            continue
        res.sizing = dataclasses.replace(res.sizing, drop=rss - held.cost,
                                         converged=held.converged)
        if baseline_span is not None:
            # The round starts at an optimum, where the residual is (nearly) orthogonal
            # to the span: its projected cost is ``rss``, the reference of both drops.
            free = size_with_baseline_free(problem, cand.name, held.program, held.theta,
                                           baseline_span, max_steps=max_steps)
            record_free_sizing(res, free, rss)
            if free_sizings is not None:
                free_sizings[res.name] = free
        res.status = CandidateStatus.SIZED
        sized[res.name] = held
    return sized
