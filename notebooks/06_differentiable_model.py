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
# # 6. The differentiable model in research
#
# The simulator is a pure JAX function of the actuator (an equinox Module) and the
# voltage, so `jax.grad`, `jax.jacfwd` and `jax.vmap` go through it. Three uses:
#
# 1. **Sensitivities**: how the step length per period depends on every parameter
#    (one gradient gives all of them).
# 2. **Experiment design**: which drive (amplitude, frequency) tells most about
#    z_ba, from the Fisher information `Jᵀ J / σ²` with J from `jacfwd`.
# 3. **Drive design**: a sawtooth-like waveform optimised by gradient descent so
#    that the slider steps a wanted distance per period with the least voltage.
#
# `STICKSLIP_NOTEBOOK_QUICK=1` shrinks grids and iteration counts for CI.

# %%
import os

import equinox as eqx
import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np
import optimistix as optx

import stickslip_jax as ss

ss.fast_cpu_loops()  # XLA compiles the simulator's small loops natively (~3x)
ss.use_compilation_cache()  # programs kept on disk ($STICKSLIP_CACHE_DIR): a rerun skips compiling

QUICK = os.environ.get("STICKSLIP_NOTEBOOK_QUICK", "0") == "1"
act = ss.lu2015_slc1720()
FS = 25_000.0
DT = 1 / FS

# %% [markdown]
# ## 1. Sensitivity of the step length to every parameter
#
# The step per period is read phase-locked: the position at the end of the third
# period minus that at the end of the second. `eqx.filter_grad` differentiates it
# with respect to every floating-point leaf of the actuator at once (85 numbers; the
# simulator's default derivative rule builds them from forward sensitivities, which
# compile in seconds where reverse mode takes minutes on a CPU); we report
# elasticities `d ln(step) / d ln(p)` (a 1 % change in p changes the step by that
# many %).

# %%
def sawtooth_jnp(amplitude, frequency, n, backward=False):
    t = jnp.arange(n) * DT
    ramp = amplitude * jnp.mod(frequency * t, 1.0)
    return jnp.where(backward, amplitude - ramp, ramp)


def step_length(actuator, amplitude=60.0, frequency=200.0, periods=3):
    n = int(round(periods * FS / frequency)) + 1
    u = sawtooth_jnp(amplitude, frequency, n)
    drive = ss.DriveContext.make(amplitude=amplitude, frequency=frequency)
    q = ss.simulate(actuator, u, dt=DT, drive=drive)
    per = int(round(FS / frequency))
    return q[-1] - q[-1 - per]


step0 = step_length(act)
grads = eqx.filter_grad(step_length)(act)
names = {
    "Mp": lambda a: a.piezo.Mp, "Dp": lambda a: a.piezo.Dp, "Kp": lambda a: a.piezo.Kp,
    "Ms": lambda a: a.slider.Ms, "Ds": lambda a: a.slider.Ds,
    "rho0": lambda a: a.friction.rho0, "z_ba_forward": lambda a: a.friction.z_ba_forward,
    "zba_ratio": lambda a: a.friction.zba_ratio,
}
elasticity = {n: float(g(grads) * g(act) / step0) for n, g in names.items()}
elasticity["PI weights (all, x same factor)"] = float(
    jnp.sum(grads.hysteresis.weights * act.hysteresis.weights) / step0)
print(f"step at 60 V, 200 Hz forward: {float(step0) * 1e9:.1f} nm per period")

# A finite-difference check on one of them: the gradient is the real derivative.
h = 1e-4
bumped = eqx.tree_at(lambda a: a.friction.z_ba_forward, act, act.friction.z_ba_forward * (1 + h))
fd = float((step_length(bumped) - step0) / (h * step0))
print(f"z_ba elasticity: gradient {elasticity['z_ba_forward']:+.4f}, finite difference {fd:+.4f}")

order = sorted(elasticity, key=lambda n: abs(elasticity[n]))
plt.figure(figsize=(7, 4))
plt.barh(order, [elasticity[n] for n in order])
plt.axvline(0, color="k", lw=0.6)
plt.xlabel("d ln(step) / d ln(parameter)")
plt.title("What sets the step length (60 V, 200 Hz, forward)")
plt.tight_layout()
plt.show()

# %% [markdown]
# ## 2. Which drive tells most about z_ba?
#
# For a recording of fixed length (20 ms) at each (amplitude, frequency), the
# Fisher information about z_ba is `I = Σ_t (∂q_t/∂z_ba)² / σ²` with σ = 1 nm of
# interferometer noise; `1/√I` is the best standard error an unbiased fit can reach
# (Cramér-Rao). `jacfwd` gives ∂q/∂z_ba along the whole trace and `vmap` does the
# whole grid in one batched call. In scanning (no slip) the trace hardly depends
# on z_ba: those drives are useless for it, and the map shows the threshold.

# %%
n_samples = int(0.02 * FS)
sigma = 1e-9


def trace_for(zba, amplitude, frequency):
    a = eqx.tree_at(lambda x: x.friction.z_ba_forward, act, zba)
    u = sawtooth_jnp(amplitude, frequency, n_samples)
    drive = ss.DriveContext.make(amplitude=amplitude, frequency=frequency)
    return ss.simulate(a, u, dt=DT, drive=drive)


def fisher(amplitude, frequency):
    dq = jax.jacfwd(trace_for)(act.friction.z_ba_forward, amplitude, frequency)
    return jnp.sum(dq**2) / sigma**2


design_amps = jnp.linspace(20.0, 80.0, 4 if QUICK else 9)
design_freqs = jnp.array([100.0, 300.0, 1000.0] if QUICK else
                         [50.0, 100.0, 200.0, 300.0, 500.0, 700.0, 1000.0])
A, F = jnp.meshgrid(design_amps, design_freqs, indexing="ij")
info = jax.jit(jax.vmap(fisher))(A.ravel(), F.ravel()).reshape(A.shape)
best_se = 1 / jnp.sqrt(info)
rel = np.asarray(best_se / act.friction.z_ba_forward)
# Pure scanning: the trace does not depend on z_ba at all (zero information).
rel = np.where(np.isfinite(rel), rel, np.nan)

plt.figure(figsize=(7, 4))
plt.pcolormesh(np.asarray(design_freqs), np.asarray(design_amps), np.log10(rel),
               shading="nearest", cmap="viridis_r")
plt.xscale("log")
plt.colorbar(label="log10 (best relative std error of z_ba)")
plt.xlabel("frequency [Hz]")
plt.ylabel("amplitude [V]")
plt.title("Cramér-Rao bound on z_ba from 20 ms of forward sawtooth")
plt.show()
i, j = np.unravel_index(np.nanargmin(rel), rel.shape)
print(f"most informative drive: {float(design_amps[i]):.0f} V at {float(design_freqs[j]):.0f} Hz "
      f"(relative std error {rel[i, j]:.2e}); least informative that slips: {np.nanmax(rel):.2e}; "
      f"{int(np.isnan(rel).sum())} drive(s) never slip and tell nothing about z_ba")

# %% [markdown]
# ## 3. A drive waveform designed by gradient descent
#
# One period is a free-form rise through K knots (kept between 0 and 60 V by a
# sigmoid) followed by the abrupt drop. We ask for a step of 150 nm per period
# and penalise the mean squared voltage, and let BFGS (optimistix) shape the rise,
# differentiating through three simulated periods.
#
# The step depends on the 8 knots through 376 voltage samples. Left alone, JAX
# would take its gradient in reverse mode through the simulator's loops, which
# compiles slowly (about a minute on a 2-core CPU with native loops).
# `ss.with_forward_jacobian` makes every derivative of the step come from its
# 8-column Jacobian built in forward mode instead (a few seconds to compile, and
# faster to run): the right trade while the inputs are few.

# %%
K = 8
frequency = 200.0
per = int(round(FS / frequency))
periods = 3
U_MAX = 60.0
target = 150e-9
drive = ss.DriveContext.make(amplitude=U_MAX, frequency=frequency)


def waveform(theta):
    knots = U_MAX * jax.nn.sigmoid(theta)
    knots = jnp.concatenate([jnp.zeros(1), knots])
    phase = jnp.arange(per) / per
    one = jnp.interp(phase, jnp.linspace(0, 1, K + 1), knots)
    return jnp.concatenate([jnp.tile(one, periods), jnp.zeros(1)])


@ss.with_forward_jacobian
def designed_step(theta):
    q = ss.simulate(act, waveform(theta), dt=DT, drive=drive)
    return q[-1] - q[-1 - per]


def loss(theta, args):
    u = waveform(theta)
    step = designed_step(theta)
    return ((step - target) / 10e-9) ** 2 + 1e-3 * jnp.mean(u**2) / U_MAX**2


theta0 = jnp.linspace(-2.0, 1.5, K)  # a sawtooth-like start
solver = optx.BFGS(rtol=1e-6, atol=1e-8)
sol = optx.minimise(loss, solver, theta0, max_steps=40, throw=False)
theta = sol.value
print(f"start: step {float(designed_step(theta0)) * 1e9:.1f} nm, "
      f"rms voltage {float(jnp.sqrt(jnp.mean(waveform(theta0) ** 2))):.1f} V")
print(f"designed: step {float(designed_step(theta)) * 1e9:.1f} nm (target {target * 1e9:.0f}), "
      f"rms voltage {float(jnp.sqrt(jnp.mean(waveform(theta) ** 2))):.1f} V, "
      f"{int(sol.stats['num_steps'])} BFGS steps, loss {float(loss(theta, None)):.2e} "
      f"(from {float(loss(theta0, None)):.2e}); "
      f"{'converged' if sol.result == optx.RESULTS.successful else 'step limit reached'}")

t = np.arange(periods * per + 1) * DT
fig, axes = plt.subplots(2, 1, figsize=(8, 5), sharex=True)
for th, label in ((theta0, "start"), (theta, "designed")):
    u = waveform(th)
    axes[0].plot(t * 1e3, u, label=label)
    q = ss.simulate(act, u, dt=DT, drive=drive)
    axes[1].plot(t * 1e3, (np.asarray(q) - float(q[0])) * 1e9, label=label)
axes[0].set_ylabel("U [V]")
axes[1].set_ylabel("q [nm]")
axes[1].set_xlabel("t [ms]")
axes[0].legend()
plt.show()
