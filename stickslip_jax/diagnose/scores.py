"""The score tests: how well each catalogue entry's signature matches the residual.

Every applicable probe of every entry is installed at zero strength. With ``J_b`` the
Jacobian of the whitened residual ``r`` in the baseline parameters and ``c`` its
derivative in the entry's strength at zero, ``c⊥`` the part of ``c`` the baseline
parameters cannot mimic, the score (Lagrange-multiplier) statistic
``S = (r·c⊥)²/|c⊥|²`` is the drop of the residual sum of squares that the entry would
buy to first order, χ²(1) when the entry is absent. Strengths of the wrong sign
(negative damping, negative delay) score ``−S``: they rank after every admissible one.

The same ``c⊥`` gives each entry's **detection limit** on the recorded protocol: the
strength ``s`` at which the part of the effect the baseline cannot mimic reaches the
tolerance of :mod:`~stickslip_jax.significance`, ``s²·|c⊥|² = τ·N``; below it, a refit could not
remove a material part of the residual. It is stated in the entry's own units and as
the RMS the effect itself would add to the traces at that strength [nm] (before the
baseline absorbs what it can), for the probe where that RMS is smallest.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..identify.parameters import ParameterSpec
from ..model.actuator import Actuator
from .budget import evaluation_work
from .catalogue import Candidate, Probe
from .problem import BaselineSpan, Problem, without_span


class InstalledProbe(NamedTuple):
    """One probe in the score test's actuator: its strength is element ``index`` of the
    quantity ``name`` (``spec``; a scalar's index is 0)."""

    candidate: Candidate
    probe: Probe
    name: str
    spec: ParameterSpec
    index: int = 0


def install_probes(act: Actuator, candidates: Sequence[Candidate],
                   hints: dict) -> tuple[Actuator, list[InstalledProbe]]:
    """The current actuator with every applicable probe at zero strength, and the
    :class:`InstalledProbe` addressing each strength.

    An entry's probes that share one spec (the coefficients of a vector quantity, the
    k-th probe its element k) are one quantity. Its probes that are extensions of one
    class with a ``bank`` (several time
    constants of creep or of the rate lag) go in as one bank extension, their strengths
    one vector: the same columns as one extension per probe (their states do not
    interact and their strokes add), from a program whose size does not grow with the
    probes (the score program of the whole catalogue: 741 kB of HLO and 24 s of XLA
    with one extension per probe, issue #27)."""
    entries: list[InstalledProbe] = []
    for cand in candidates:
        # Probes that can share a bank, together (in the order they first appear).
        groups: dict[object, list[Probe]] = {}
        for probe in cand.probes(act, hints):
            ext = probe.extension
            if ext is not None and hasattr(type(ext), "bank"):
                key = (type(ext), probe.field, probe.spec.scale, probe.spec.unit)
            elif ext is None:  # probes sharing one spec: the elements of one vector
                key = ("spec", id(probe.spec))
            else:
                key = id(probe)
            groups.setdefault(key, []).append(probe)
        for members in groups.values():
            probe = members[0]
            try:
                if probe.extension is not None:
                    ext = (type(probe.extension).bank([m.extension for m in members])
                           if len(members) > 1 else probe.extension)
                    i = len(act.extensions)
                    act = act.with_extension(ext)
                    strength = probe.strength_getter()
                    spec = ParameterSpec(lambda a, i=i, f=strength: f(a.extensions[i]),
                                         "linear", probe.spec.scale, probe.spec.unit)
                else:
                    act = probe.install(act)
                    spec = probe.spec
            except ValueError:
                continue  # the slot is taken by an accepted effect
            name = f"probe{len(entries)}"
            entries.extend(InstalledProbe(cand, m, name, spec, k)
                           for k, m in enumerate(members))
    return act, entries


MAX_PROBE_QUANTITIES = 6
"""The score test installs its probes in programs of at most this many probe
quantities each (an extension, a bank of them or a parameter: one quantity), as
equal in size as the entries allow (:func:`probe_batches`). The columns are the same
whichever program holds them; what changes is the compiling: LLVM's time on a
program's native-loop kernel grows faster than the kernel. The whole catalogue's 11
quantities in one program compiled in 23, 27 and 29 s; in two of 5 and 6, in 20, 19
and 23 s together; in three (3, 5, 3), 33 s (each program also compiles the
simulator once); the second call costs about 0.3 s more (issue #27, measured at
8196fdd: benchmarks/experiments/results/diagnose_score_batches.json)."""


def probe_batches(act: Actuator, candidates: Sequence[Candidate], hints: dict,
                  most: int = MAX_PROBE_QUANTITIES) -> list[list[Candidate]]:
    """``candidates`` in consecutive batches of at most ``most`` probe quantities each
    where an entry's own allow it (an entry is never split), in as few batches as
    that takes, cut where the largest batch is smallest (the earliest such cuts)."""
    sizes = [len({e.name for e in install_probes(act, [c], hints)[1]}) for c in candidates]
    total = sum(sizes)
    k = max(1, min(len(sizes), -(-total // most)))

    def bounds(cuts: tuple[int, ...]) -> list[tuple[int, int]]:
        return list(itertools.pairwise((0, *cuts, len(sizes))))

    # min keeps the first of equals: the earliest cuts (combinations come in order).
    cuts = min(itertools.combinations(range(1, len(sizes)), k - 1),
               key=lambda c: max(sum(sizes[a:b]) for a, b in bounds(c)))
    return [list(candidates[a:b]) for a, b in bounds(cuts)]


def score_candidates(problem: Problem, act: Actuator, base_names: list[str],
                     candidates: Sequence[Candidate], hints: dict,
                     base_jacobian: np.ndarray | None = None):
    """Score test of every probe (see the module docstring). Returns ``(scores,
    limits, span)``: ``scores`` a dict ``name → (score, strength, probe, shift)`` with each
    candidate's best probe, the Gauss-Newton strength and the baseline θ shift that
    goes with it; ``limits`` a dict ``name →`` detection limit (module docstring:
    ``strength`` in ``unit``, ``effect_nm``, ``probe``), empty until the problem has
    its :attr:`~.problem.Problem.significance`; ``span`` the span of ``J_b``
    (:class:`~.problem.BaselineSpan`), what the baseline can mimic to first order
    (:mod:`.sizing` sizes in its complement too).

    ``base_jacobian``: ``J_b`` at ``act`` in the coordinates of ``base_names`` around it,
    when a fit ended there with it (the baseline's polish,
    :func:`~.problem.recentred`); then only the probes' columns are simulated."""
    r, base_cols, entries, probe_cols = None, base_jacobian, [], []
    for batch in probe_batches(act, candidates, hints):
        probe_act, installed = install_probes(act, batch, hints)
        specs = {e.name: e.spec for e in installed}
        with_base = base_cols is None  # the baseline's columns from the first program
        names = base_names + list(specs) if with_base else list(specs)
        program = problem.program(probe_act, names, specs)
        r_batch, jac = program(np.zeros(program.pmap.size))
        problem.budget.charge(evaluation_work(problem.samples, program.simulated_columns,
                                              program.factor))
        r = r_batch if r is None else r
        if with_base:
            base_cols = jac[:, :program.pmap.size - len(installed)]
        slices = program.pmap.slices()
        entries += installed
        probe_cols += [jac[:, slices[e.name].start + e.index] for e in installed]
    base_cols = np.asarray(base_cols)
    # The baseline's columns, then one column per probe in the order of ``entries``.
    jac = np.concatenate([base_cols, np.stack(probe_cols, axis=1)
                          if probe_cols else base_cols[:, :0]], axis=1)
    n_base = base_cols.shape[1]
    span = BaselineSpan.of(jac[:, :n_base])
    q = span.basis
    out: dict[str, tuple[float, float, Probe, np.ndarray]] = {}
    limits: dict[str, dict] = {}
    sig = problem.significance
    for k, (cand, probe, _, spec, _) in enumerate(entries):
        c = jac[:, n_base + k]
        c_perp = without_span(q, c)
        cc = float(c_perp @ c_perp)
        if sig is not None and cc > 0:
            limit = _detection_limit(problem, c, cc, spec, probe)
            if cand.name not in limits or limit["effect_nm"] < limits[cand.name]["effect_nm"]:
                limits[cand.name] = limit
        if cc <= 1e-12 * max(float(c @ c), 1e-300):
            score, beta = 0.0, 0.0
        else:
            beta = -float(r @ c_perp) / cc
            score = float(r @ c_perp) ** 2 / cc
            if probe.sign > 0 and beta < 0:
                # Wrong sign to first order: a negative score, so that the entry ranks
                # after every admissible one (a large effect can still turn the sign
                # around; see diagnose's ``top``).
                score, beta = -score, -beta
        # The baseline's share of the Gauss-Newton step that goes with the strength
        # β: an effect the baseline partly mimics (a rate lag is a creep plus a PI
        # slope change) only pays once the baseline gives back what it absorbed.
        shift = span.move(r + c * beta)
        # Each entry's best probe: the highest admissible score, or, when every probe
        # of the entry has the wrong first-order sign, the strongest of them (the one
        # worth sizing in case the sign turns around).
        if cand.name not in out or (score >= 0, abs(score)) > (out[cand.name][0] >= 0,
                                                                abs(out[cand.name][0])):
            out[cand.name] = (score, beta * spec.scale, probe, shift)
    return out, limits, span


def _detection_limit(problem: Problem, c: np.ndarray, cc: float, spec: ParameterSpec,
                     probe: Probe) -> dict:
    """The detection limit of one probe (module docstring): ``c`` its whitened
    Jacobian column, ``cc = |c⊥|²``."""
    sig = problem.significance
    theta = float(np.sqrt(sig.tolerance_rss / cc))
    # The effect itself in metres: un-whiten the column (each recording's σ).
    rows = np.asarray(c).reshape(len(problem.sigmas), -1) * problem.sigmas[:, None]
    effect_m = theta * float(np.sqrt(np.sum(rows**2) / sig.n_obs))
    return {"strength": theta * abs(float(spec.scale)), "unit": spec.unit,
            "effect_nm": effect_m * 1e9, "probe": probe.label}

