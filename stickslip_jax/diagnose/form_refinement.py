"""An accepted entry's form refined within its class.

An entry is accepted in the form its refit fits (a tanh slew limit, ...). When the
model it makes is still beyond the noise tolerance, the residue may be that form's,
not another effect's: a current-limited amplifier's hard corner left mean (e/σ)² 3.3
under the best tanh on the concealed set, with the baseline at its truth. The entry
then offers richer forms of its class that start exactly at its fitted model
(:meth:`~.catalogue.base.CatalogueEntry.refined_forms`: one more parameter at the
value that reduces it to the fitted form), refitted with every baseline quantity (the
other accepted entries held).

A refined form is kept by the rules that accept an entry, applied to the parameters
it adds: its ΔBIC (``ΔRSS + added·ln N``) below :attr:`~.Policy.bic_min` and what it
removes material (beyond the tolerance of the noise estimate and the numerical floor).
No threshold of its own. The accepted entry's record then holds the refined refit (its
parameters, costs and shares against the round's start), and a note says what moved.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..identify.parameters import ParameterMap
from ..model.actuator import Actuator
from ..significance import Significance, per_recording_chi2
from .catalogue import candidate
from .policy import Policy
from .problem import Problem, baseline_free
from .records import amended
from .results import CandidateResult
from .rules import acceptable


def refined_outcome(problem: Problem, significance: Significance, policy: Policy,
                    res: CandidateResult, fitted: Actuator, out, specs: dict):
    """``res``'s refit record with the refined refit ``out`` (``fitted``, freeing
    ``specs``) in place of its own, every share against the same round start."""
    old = res.refit
    n_obs = problem.n_obs
    rss_new = float(out.cost_end)
    added = old.added + len(specs) - len(old.params)
    excess = old.rss_before - n_obs
    return dataclasses.replace(
        old, actuator=fitted,
        params={n: float(np.asarray(s.getter(fitted))) for n, s in specs.items()},
        converged=bool(out.converged), rss_after=rss_new,
        nrmse_after=float(problem.nrmse_from_whitened(out.residual).mean()),
        criterion_delta=rss_new - old.rss_before + added * np.log(n_obs), added=added,
        explained=(excess - (rss_new - n_obs)) / excess
        if excess > policy.excess_min * n_obs else np.nan,
        chi2_after=rss_new / n_obs,
        adequate=significance.adequate(rss_new, per_recording_chi2(out.residual,
                                                                   problem.counts)),
        material=significance.material(old.rss_before, rss_new),
        removed_nm=significance.nm(old.rss_before - rss_new),
        removed_noise_share=(old.rss_before - rss_new) / n_obs)


def _carried_on(problem: Problem, fitted: Actuator, out, names: list[str], specs: dict,
                columns: int, max_steps: int, what: str, notes: list[str]):
    """A refined refit ``out`` (``fitted``) that stopped at its step cap, carried on from
    there by up to ``max_steps`` steps, every parameter free, starting nearly
    Gauss-Newton, as a round's refits are (:class:`~.passes.CarryOnDeciding`): it is
    judged at its convergence. Kept when it ends lower; skipped, and said, when the
    work budget cannot hold it. Returns the model and the solve's result."""
    need = problem.fit_estimate(fitted, columns, max_steps)
    if not problem.budget.allows(need):
        notes.append(f"Carrying on {what}: {problem.budget.skip(f'carrying on {what}', need)}.")
        return fitted, out
    try:
        carried, _, more = problem.fit(fitted, names, specs, label=f"{what}, carried on",
                                       max_steps=max_steps, initial_damping=1e-3)
        problem.plan_factor(carried)  # a model the simulator can step on these data
    except ValueError:
        return fitted, out
    return (carried, more) if more.cost_end < out.cost_end else (fitted, out)


def refine_forms(problem: Problem, act: Actuator, rss: float, accepted: Sequence[CandidateResult],
                 hints: dict, *, significance: Significance, policy: Policy, max_steps: int,
                 notes: list[str]) -> tuple[Actuator, float]:
    """``act`` (whitened RSS ``rss``, holding the ``accepted`` entries) with each
    accepted entry's richer forms tried in turn (``max_steps`` per refit stage), the
    ones the module's rule keeps in place; returns the model and its RSS. Each try is
    said in ``notes``; one the work budget cannot hold is skipped and said."""
    n_obs = problem.n_obs
    for res in accepted:
        for start, specs in candidate(res.name).refined_forms(act, hints):
            names = baseline_free(start, problem.data, problem.fix) + list(specs)
            what = f"the form of {res.name} refined ({', '.join(specs)})"
            columns = int(np.size(ParameterMap.make(start, names, specs).zeros()))
            need = problem.refit_estimate(start, columns, max_steps)
            if not problem.budget.allows(need):
                notes.append(f"{what[0].upper()}{what[1:]}: "
                             f"{problem.budget.skip(what, need)}.")
                continue
            try:
                # The start is the fitted model (the new parameters at their
                # neutral values): nearly Gauss-Newton from the first step.
                fitted, _, out = problem.refit(start, names, specs,
                                               label=f"refine {res.name}",
                                               max_steps=max_steps, initial_damping=1e-3)
            except ValueError as err:
                notes.append(f"{what[0].upper()}{what[1:]}: not refitted ({err}).")
                continue
            if not out.converged:
                fitted, out = _carried_on(problem, fitted, out, names, specs, columns,
                                          max_steps, what, notes)
            rss_new = float(out.cost_end)
            added = len(specs) - len(res.params)
            delta = rss_new - rss + added * np.log(n_obs)
            keep = delta < policy.bic_min and significance.material(rss, rss_new)
            said = (f"{what[0].upper()}{what[1:]}: mean (e/σ)² {rss / n_obs:.4g} → "
                    f"{rss_new / n_obs:.4g}, ΔBIC {delta:.1f} for {added} more "
                    f"parameter{'s' if added != 1 else ''} ({out.message})")
            if keep:
                res.refit = refined_outcome(problem, significance, policy, res, fitted,
                                            out, specs)
                values = ", ".join(f"{k}={v:.4g}" for k, v in res.params.items())
                res.add_note(f"form refined: {values}")
                # A partial answer whose refined form explains the residual is whole.
                res.decision = amended(res.decision,
                                       partial=res.partial and not acceptable(res, policy))
                act, rss = fitted, rss_new
                said += ": kept, the entry's form is the refined one."
            else:
                said += ": not kept (the rules that accept an entry, for what it adds)."
            notes.append(said)
            problem.say(f"[form] {said}")
    return act, rss
