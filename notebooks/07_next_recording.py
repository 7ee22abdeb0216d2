# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#       format_version: '1.3'
#       jupytext_version: 1.19.7
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 7. The next recording: when two physics tie, design the drive that tells them apart
#
# A diagnosis can end with an entry named but **tied**: a rival explains the residual
# about as well, and the recordings cannot say which is right. Recording the same
# protocol again rarely helps, because the two models differ in the same place on
# every one of those drives. `design_experiment` (CLI: `stickslip design-experiment
# DATA --diagnosis OUT --out PLAN`) uses the differentiable model to choose drives
# where they differ *after* each is refitted to the other's traces.
#
# The data: development set 40 of the project's random split `dev2`. It is an actuator
# with its own parameters and one hidden effect, made by the independent generator
# (16x finer steps than a fit uses, 0.72 nm noise). What it hides is read only at the
# end. The loop here:
#
# 1. diagnose the protocol's recordings: an entry is named, tied with rivals;
# 2. plan the next recordings within the amplifier's limits and the same recording time;
# 3. record them (here: the generator at the set's truth, fresh noise);
# 4. diagnose again with the new recordings added: is the tie gone, and is the name right?
#
# Full mode: the 17 recordings of the paper's protocol, the baseline identified from
# the default profile, every catalogue entry, and the protocol recorded once more for
# the same time as a control arm (three diagnoses and a plan: about half an hour on two
# cores, what `benchmarks/bench_design_loop.py` takes per set).
# `STICKSLIP_NOTEBOOK_QUICK=1` (what CI runs) keeps 5 of the recordings, starts the
# baseline from the set's truth without its effect (`--skip-identify`), one round of
# at most three refits, and no control arm (2 min measured beside two other jobs).

# %%
import os
import tempfile
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import matplotlib.pyplot as plt
import numpy as np
from IPython.display import Image, display

import stickslip_jax as ss
from stickslip_jax.design.report import plot_plan
from stickslip_jax.diagnose.locate import residual_of
from stickslip_jax.diagnose.report import write_diagnosis
from stickslip_jax.simulate import simulate_recordings
from stickslip_jax.synthetic import paper_protocol, simulate_set
from stickslip_jax.testing import random_sets

ss.fast_cpu_loops()  # XLA compiles the simulator's small loops natively (~3x)
ss.use_compilation_cache()  # programs kept on disk ($STICKSLIP_CACHE_DIR): a rerun skips compiling

QUICK = os.environ.get("STICKSLIP_NOTEBOOK_QUICK", "0") == "1"
spec = random_sets.split_sets("dev2")[40]
drives = paper_protocol()
if QUICK:
    keep = {"step_40V", "sine_40V_50Hz", "saw_60V_100Hz_fwd", "saw_60V_500Hz_fwd",
            "saw_60V_500Hz_bwd"}
    drives = [d for d in drives if d.name in keep]
recordings = random_sets.make_recordings(spec, drives)
FIX = {"Ms": 0.0247}
if QUICK:
    init = random_sets.truth_actuator(spec)
    settings = dict(identify_steps=(), max_rounds=1, top=3, max_steps=20, size_at_most=3)
else:
    init = ss.lu2015_slc1720()
    settings = {}
work = Path(tempfile.mkdtemp(prefix="stickslip-next-recording-"))
print(f"{len(recordings)} recordings, {sum(r.n * r.dt for r in recordings):.3f} s in all, "
      f"noise {spec.noise_m * 1e9:.2f} nm; work folder {work}")


def diagnosed(recs, folder):
    """Diagnose ``recs`` as ``stickslip diagnose`` does and write its outputs to
    ``folder`` (what ``design_experiment`` reads); the named entries and their ties."""
    t0 = time.perf_counter()
    d = ss.diagnose(recs, init=init, fix=FIX, **settings)
    write_diagnosis(d, folder, figures=False)
    ties = {c.name: list(c.indistinguishable_from) for c in d.accepted}
    print(f"{len(recs)} recordings diagnosed in {time.perf_counter() - t0:.0f} s: "
          f"{d.verdict}; named {[c.name for c in d.accepted] or 'nothing'}")
    for name, rivals in ties.items():
        print(f"  {name}: " + (f"tied with {', '.join(rivals)}" if rivals else "no tie"))
    return d, ties


# %% [markdown]
# ## 1. The diagnosis ends in a tie
#
# The named entry explains the excess over the noise, but for each rival the refit of
# the rival alone leaves a residual within the diagnosis's tolerance of the named one:
# on these recordings the two are the same physics.

# %%
before, ties_before = diagnosed(recordings, work / "diagnosis")
assert any(ties_before.values()), "the reduced diagnosis was expected to end tied"

# %% [markdown]
# ## 2. The plan
#
# Each question is a pair of models, each refitted to the other's traces. For every
# candidate drive (sawtooths both ways, sines and steps at the amplitudes and
# frequencies the amplifier allows) the planner simulates both models and takes
# their Jacobians. From these it predicts the wrong model's excess cost after a refit
# (to first order), for any mix of recordings. It then adds five-period units, one at
# a time, choosing each for the most evidence per second, until the time (as long as
# the recordings so far) is spent. Evidence over the tolerance above 1 means told apart.

# %%
t0 = time.perf_counter()
plan = ss.design_experiment(recordings, work / "diagnosis", fix=FIX)
print(f"planned in {time.perf_counter() - t0:.0f} s from {plan.candidates} candidates: "
      f"{len(plan.recordings)} recordings, {plan.planned_time_s:.3f} s")
print(f"\n{'question':42s} {'now':>8s} {'protocol again':>15s} {'plan':>9s}")
for q in plan.questions:
    print(f"{q.label:42s} {q.ratio_now:8.3g} {q.ratio_default:15.3g} {q.ratio_designed:9.3g}")
print("\nrecordings:")
for r in plan.recordings:
    print(f"  {r.drive.name:22s} {r.drive.duration_s * 1e3:6.1f} ms  for: {r.serves}")
display(Image(filename=str(plot_plan(plan, work / "plan.png"))))
fig, ax = plt.subplots(figsize=(10, 3.2))
for r in plan.recordings[:4]:
    rec = r.drive.recording()
    ax.plot(rec.time_s * 1e3, rec.voltage_V, lw=0.8, label=r.drive.name)
ax.set_xlabel("t [ms]")
ax.set_ylabel("drive [V]")
ax.set_title("the plan's first recordings")
ax.legend(fontsize=7)
plt.tight_layout()
plt.show()

# %% [markdown]
# ## 3. Record the plan, diagnose again
#
# The plan's drives are recorded at the set's truth (its hidden effect included) by
# the independent generator, with noise of the set's level and a new seed, and added to
# the recordings. In full mode the control arm records the protocol again, for the
# same time, with another seed.

# %%
truth = random_sets.hidden_actuator(spec)
designed = simulate_set(truth, [r.drive for r in plan.recordings], noise_m=spec.noise_m,
                        seed=spec.recording_seed + 1_000_003)
after, ties_after = diagnosed(recordings + designed, work / "diagnosis_with_plan")
if not QUICK:
    repeats = round(plan.total_time_s / sum(r.n * r.dt for r in recordings))
    again = simulate_set(truth, [d for d in drives for _ in range(repeats)],
                         noise_m=spec.noise_m, seed=spec.recording_seed + 2_000_003)
    control, ties_control = diagnosed(recordings + again, work / "diagnosis_protocol_again")

# %% [markdown]
# ## The answer
#
# Why the plan settles it: on a recording of the plan, the two models that tied (each
# fitted to the first recordings only, neither to this one) predict different traces,
# and only one follows what was recorded (in the quick mode the rival, a constant load,
# predicts the slider creeping under the 473 Hz sine by a hundred nanometres). Then
# what the set hid.

# %%
named_before = ss.load_params(work / "diagnosis" / "params.json")
rival_name = sorted(ties_before[next(n for n, r in ties_before.items() if r)])[0]
rival = ss.load_params(work / "diagnosis" / "rivals" / f"{rival_name}.json")
rec = designed[0]
fig, ax = plt.subplots(figsize=(10, 3.4))
for act, label in ((named_before, f"{[c.name for c in before.accepted][0]} (named)"),
                   (rival, f"{rival_name} (its rival)")):
    q = simulate_recordings(act, [rec])[0]
    e = residual_of(rec, q)
    ax.plot(rec.time_s * 1e3, e * 1e9, lw=0.6,
            label=f"{label}: RMS {np.sqrt(np.mean(e ** 2)) * 1e9:.2f} nm")
ax.axhspan(-spec.noise_m * 1e9, spec.noise_m * 1e9, color="0.85", zorder=0, label="±σ")
ax.set_xlabel("t [ms]")
ax.set_ylabel("recorded − predicted [nm]")
ax.set_title(f"{rec.name}, a recording of the plan, against the two tied models")
ax.legend(fontsize=8)
plt.tight_layout()
plt.show()
print(f"the set hid: {spec.effect} ({spec.form} form, strength {spec.strength:.4g})")
for c in after.accepted:
    print(f"named with the plan: {c.name} {c.params}")
right = [c.name for c in after.accepted][:1] == [spec.effect]
right = right and not ties_after.get(spec.effect)
print(f"right and untied with the plan: {right}")
if not QUICK:
    named = [c.name for c in control.accepted]
    print(f"with the protocol again: named {named or 'nothing'}, ties {ties_control}")
assert right
