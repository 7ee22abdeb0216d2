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
# # 3. The z_ba surface, the velocity map and open-loop drive
#
# The paper identifies the break-away strain z_ba against amplitude at one
# frequency (its Fig. 8) and leaves as future work a z_ba **surface** over the
# whole drive workspace (amplitude x frequency x direction), for control. Here:
#
# 1. a grid of stepping recordings from an actuator whose z_ba really depends on the
#    drive (a tanh in amplitude, a square root in frequency, both directions);
# 2. z_ba per recording in **one vmapped** least-squares solve;
# 3. a smooth surface through those points, with its goodness of fit and where the
#    data support it;
# 4. the velocity map of the model with and without the surface (one compiled,
#    vmapped grid simulation);
# 5. velocity inversion: which amplitude gives 50 µm/s at each frequency.
#
# CLI equivalents: `stickslip zba-surface`, `stickslip sweep`, `stickslip drive`.

# %%
import os
import time

import jax

jax.config.update("jax_enable_x64", True)
import matplotlib.pyplot as plt
import numpy as np

import stickslip_jax as ss
from stickslip_jax.sweep.zba_surface import plot_zba_surface
from stickslip_jax.synthetic import example_zba, with_drive_dependent_zba

ss.fast_cpu_loops()  # XLA compiles the simulator's small loops natively (~3x)
ss.use_compilation_cache()  # programs kept on disk ($STICKSLIP_CACHE_DIR): a rerun skips compiling

QUICK = os.environ.get("STICKSLIP_NOTEBOOK_QUICK", "0") == "1"

# %% [markdown]
# ## An actuator whose z_ba depends on the drive
#
# A friction law is one small class: `ss.synthetic.DriveDependentZba` takes the
# elasto-plastic law and makes z_ba a function of the drive's amplitude, frequency
# and direction (the `DriveContext` every recording carries). The function used here,
# `example_zba`, is a tanh in amplitude and a square root in frequency, not a
# quadratic: the surface we fit later is one, so the fit is honest about its form
# error.

# %%
true_zba = example_zba
base = ss.lu2015_slc1720()
truth = with_drive_dependent_zba(base, true_zba)

amps = (40.0, 60.0, 80.0) if QUICK else (40.0, 50.0, 60.0, 70.0, 80.0)
freqs = (100.0, 300.0, 700.0) if QUICK else (50.0, 100.0, 200.0, 400.0, 700.0)
specs = [ss.DriveSpec("sawtooth", a, f, d, 4 / f)
         for d in ("forward", "backward") for a in amps for f in freqs]
grid_recordings = ss.simulate_set(truth, specs, noise_m=1e-9, seed=11)
print(f"{len(grid_recordings)} stepping recordings, 4 periods each, 1 nm noise")

# %% [markdown]
# ## z_ba per recording, in one batched solve
#
# Every other parameter is held at the identified values (here: the profile the
# grid was made from); each recording gets its own z_ba. The solve is one
# `vmap`ped Levenberg-Marquardt over all recordings, not a Python loop.

# %%
t0 = time.perf_counter()
points = ss.fit_zba_points(base, grid_recordings)
print(f"{len(points.names)} points in {time.perf_counter() - t0:.1f} s "
      f"(compilation included); all converged: {bool(points.converged.all())}")
true_values = np.asarray(true_zba(points.amplitude_V, points.frequency_Hz,
                                  points.backward.astype(float)))
err = points.z_ba_m / true_values - 1
print(f"largest error against the truth: {100 * np.max(np.abs(err)):.3f} %; "
      f"median |error| / std error: "
      f"{np.median(np.abs(points.z_ba_m - true_values) / points.std_error_m):.2f}")

# %% [markdown]
# ## The surface
#
# A quadratic in amplitude and log10(frequency) per direction, with R², RMS and
# leave-one-out RMS; the ranges it is supported on are stored with it, and the
# surface refuses to be trusted outside them.

# %%
fit = ss.fit_zba_surface(points)
for direction, stats in fit.stats.items():
    print(direction, {k: (round(v, 4) if isinstance(v, float) else v) for k, v in stats.items()})
plot_zba_surface(points, fit)

# %% [markdown]
# ## Velocity maps: constant z_ba vs the surface
#
# `velocity_map` simulates the whole grid in one compiled, vmapped run and reads
# the steady-state velocity phase-locked (period end to period end, after the
# start-up periods). With the surface, each grid point uses the z_ba of its drive.

# %%
map_amps = np.linspace(30, 80, 6 if QUICK else 11)
map_freqs = np.array([50, 100, 200, 500, 1000] if QUICK else
                     [50, 100, 150, 200, 300, 500, 700, 1000])
grid = ss.DriveGrid.make(map_amps, map_freqs, "both")
with_surface = ss.with_zba_surface(base, fit.surface)
t0 = time.perf_counter()
vmap_const = ss.velocity_map(base, grid, periods=6 if QUICK else 10)
vmap_surf = ss.velocity_map(with_surface, grid, periods=6 if QUICK else 10)
print(f"{2 * len(grid)} grid simulations in {time.perf_counter() - t0:.1f} s")
vmap_surf.plot()

# %%
n_a, n_f = map_amps.size, map_freqs.size
v_c = vmap_const.velocity_m_s.reshape(2, n_f, n_a) * 1e6
v_s = vmap_surf.velocity_m_s.reshape(2, n_f, n_a) * 1e6
fig, axes = plt.subplots(1, 2, figsize=(11, 3.8), sharey=True)
for ax, d, name in zip(axes, range(2), ("forward", "backward"), strict=True):
    for j in range(0, n_f, max(1, n_f // 4)):
        line, = ax.plot(map_amps, np.abs(v_s[d, j]), label=f"{map_freqs[j]:.0f} Hz, surface")
        ax.plot(map_amps, np.abs(v_c[d, j]), "--", color=line.get_color())
    ax.set_title(f"{name} (dashed: constant z_ba)")
    ax.set_xlabel("amplitude [V]")
axes[0].set_ylabel("|velocity| [µm/s]")
axes[0].legend(fontsize=7)
plt.show()

# %% [markdown]
# ## Open-loop drive: the amplitude for a wanted velocity
#
# `drive_for_velocity` brackets the target on a coarse velocity map and refines
# the amplitude per frequency by secant steps on batched simulations.

# %%
choices, unreachable = ss.drive_for_velocity(
    with_surface, -50e-6, frequencies=[100.0, 200.0, 500.0] if QUICK else
    [50.0, 100.0, 200.0, 500.0, 1000.0], amplitudes=np.linspace(20, 80, 7))
print(f"{'f [Hz]':>7s} {'A [V]':>7s} {'v [µm/s]':>9s} {'step [nm]':>10s} reached")
for c in choices:
    print(f"{c.frequency_Hz:7.0f} {c.amplitude_V:7.2f} {c.velocity_m_s * 1e6:9.2f} "
          f"{c.step_m * 1e9:10.1f} {c.reached}")
print("cannot reach 50 µm/s backward at:", unreachable or "none")
