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
# # 1. A tour of the model
#
# The actuator of Lu et al. 2015 (SLC-1720-S-HV, Y axis) with the default parameter
# profile: how the same sawtooth shape gives **scanning** (stick only: the slider
# follows the piezo and comes back) or **stepping** (stick, then slip on the
# abrupt edge: the slider keeps a net step per period), why the drive direction
# matters, what the friction state `z`, the transition `α` and the friction force
# `Ff` do through one period, and the step-response spectrum with its two modes and
# antiresonance. The shapes are those of the paper's Fig. 6, 9 and 10.
#
# Set `STICKSLIP_NOTEBOOK_QUICK=1` for the reduced sizes CI uses.

# %%
import os

import jax

jax.config.update("jax_enable_x64", True)
import matplotlib.pyplot as plt
import numpy as np

import stickslip_jax as ss

ss.fast_cpu_loops()  # XLA compiles the simulator's small loops natively (~3x)
ss.use_compilation_cache()  # programs kept on disk ($STICKSLIP_CACHE_DIR): a rerun skips compiling

QUICK = os.environ.get("STICKSLIP_NOTEBOOK_QUICK", "0") == "1"
act = ss.lu2015_slc1720()
params = ss.params_from_actuator(act)
print({k: v for k, v in params.items() if not k.startswith("pi_")})
print(f"{len(params['pi_weights'])} PI operators, thresholds 0 to "
      f"{params['pi_thresholds'][-1]:.1f} V")

# %% [markdown]
# ## Scanning vs stepping (Fig. 9 and 10)
#
# A forward sawtooth rises slowly and drops abruptly. At 20 V the friction holds on
# the drop: the slider rides back with the piezo (scanning). At 40 and 60 V the drop
# is too fast: the inertia force exceeds what the contact can transmit, the contact
# slips and the slider keeps a step. Backward drive mirrors this, with its own
# break-away strain `z_ba(−)`, so the speed differs between directions.

# %%
frequency = 100.0
periods = 3 if QUICK else 6
cases = [(20.0, "forward"), (40.0, "forward"), (60.0, "forward"),
         (40.0, "backward"), (60.0, "backward")]
fig, axes = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
for amplitude, direction in cases:
    t, u = ss.sawtooth(amplitude, frequency, direction=direction, duration_s=periods / frequency)
    drive = ss.DriveContext.make(backward=direction == "backward",
                                 amplitude=amplitude, frequency=frequency)
    q = np.asarray(ss.simulate(act, u, dt=t[1] - t[0], drive=drive))
    label = f"{amplitude:.0f} V {direction}"
    axes[0].plot(t * 1e3, u, label=label)
    axes[1].plot(t * 1e3, (q - q[0]) * 1e6, label=label)
axes[0].set_ylabel("U [V]")
axes[1].set_ylabel("q [µm]")
axes[1].set_xlabel("t [ms]")
axes[1].legend(ncol=2, fontsize=8)
axes[0].set_title(f"sawtooth drives at {frequency:.0f} Hz")
plt.show()

# %% [markdown]
# ## Inside one period: z, α and the friction force
#
# `simulate_states` keeps every state. During the slow ramp the contact sticks: `z`
# grows with the relative displacement, α stays 0 while |z| < z_ba and the friction
# force `Ff = ρ0·z` carries the slider. On the abrupt edge the relative velocity
# reverses, |z| runs into the transition zone (α → 1) and saturates at |z_ss| = z_ba
# / 0.667: the contact slips at the kinetic level `f_c = ρ0·z_ss`. The step per
# period is what the slider keeps of the ramp minus what it loses on the edge.

# %%
amplitude, frequency = 60.0, 100.0
t, u = ss.sawtooth(amplitude, frequency, direction="forward", duration_s=3 / frequency)
drive = ss.DriveContext.make(amplitude=amplitude, frequency=frequency)
traj = ss.simulate_states(act, u, dt=t[1] - t[0], drive=drive)
fr = act.friction
z = np.asarray(traj.z)
xdot = np.asarray(traj.v1 - traj.v2)
zss = float(fr.zss_magnitude(0.0, drive))
alpha = np.where(z * xdot > 0,
                 np.asarray(ss.transition_alpha(np.abs(z), fr.z_ba(drive), zss)), 0.0)
last = t >= 2 / frequency  # the third period, after start-up
tp = (t[last] - t[last][0]) * 1e3
fig, axes = plt.subplots(4, 1, figsize=(8, 8), sharex=True)
axes[0].plot(tp, np.asarray(traj.x1)[last] * 1e6, label="x1 (piezo tip)")
axes[0].plot(tp, np.asarray(traj.x2)[last] * 1e6, label="x2 (slider)")
axes[0].set_ylabel("[µm]")
axes[0].legend(fontsize=8)
axes[1].plot(tp, z[last] * 1e6)
for level in (float(fr.z_ba(drive)), zss):
    axes[1].axhline(level * 1e6, color="grey", lw=0.7, ls="--")
    axes[1].axhline(-level * 1e6, color="grey", lw=0.7, ls="--")
axes[1].set_ylabel("z [µm]")
axes[2].plot(tp, alpha[last])
axes[2].set_ylabel("α")
axes[3].plot(tp, np.asarray(traj.friction)[last])
axes[3].set_ylabel("Ff [N]")
axes[3].set_xlabel("time in period [ms]")
axes[0].set_title("60 V, 100 Hz forward: the third period (dashed: ±z_ba, ±|z_ss|)")
plt.show()
print(f"z_ba = {float(fr.z_ba(drive)) * 1e6:.3f} µm, |z_ss| = {zss * 1e6:.3f} µm, "
      f"f_c = {float(fr.coulomb_force(drive)):.2f} N")

# %% [markdown]
# ## The step response and its spectrum (Fig. 6)
#
# A 40 V step is small enough for the contact to stick: the piezo and the slider
# form a two-mass chain. The measured output q = x1 + x2 shows both modes (the
# paper measured 595 and 1633 Hz) and the antiresonance between them (725 Hz)
# that only the driven oscillator has. The linearised chain
# (`ss.frequency_response`) gives the same spectrum in closed form.

# %%
duration = 0.02 if QUICK else 0.05
t, u = ss.step(40.0, duration_s=duration)
q = np.asarray(ss.simulate(act, u, dt=t[1] - t[0]))
after = t >= 2e-3
x = q[after] - q[after].mean()
x = x - np.polyval(np.polyfit(t[after], x, 1), t[after])
spectrum = np.abs(np.fft.rfft(x * np.hanning(x.size))) ** 2
f = np.fft.rfftfreq(x.size, t[1] - t[0])
band = (f > 100) & (f < 5000)
modes = ss.stick_modes(act)
print(modes)
h = np.abs(np.asarray(ss.frequency_response(act, f[band]))) ** 2

fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
axes[0].plot(t * 1e3, q * 1e6)
axes[0].set_xlabel("t [ms]")
axes[0].set_ylabel("q [µm]")
axes[0].set_title("40 V step")
axes[1].semilogy(f[band], spectrum[band] / spectrum[band].max(), label="simulated step (PSD)")
axes[1].semilogy(f[band], h / h.max(), label="|Q/Γ|² of the stick chain", lw=0.8)
axes[1].set_xlabel("f [Hz]")
axes[1].set_ylabel("normalised")
axes[1].legend(fontsize=8)
plt.show()

# %% [markdown]
# The mode frequencies of the default profile and the paper's measured ones differ
# a little: the paper's table and its spectrum are not mutually consistent (see
# docs/model.md and `ss.spectrum_consistency`); the profile keeps the table's values.

# %%
print(ss.spectrum_consistency(595.0, 1633.0, 725.0))
