"""Nguyen eq. 1-4, the tilting-hemisphere actuator: its small-tilt reduction to the
paper's piezo element holds where it says it does, and it drives a stick-slip runner."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import stickslip_jax as ss
from stickslip_jax.model.hemisphere import TiltingHemisphere, hemisphere_rates, with_hemisphere

# A ruby hemisphere of 0.5 mm radius on columns 0.4 mm off its axis.
H = TiltingHemisphere(m_a=1.0e-6, I_a=0.26e-6 * 0.5e-3**2, R=0.5e-3, a=0.1875e-3, r=0.4e-3,
                      C=2e4, D=0.0, F_n=0.5, F_ga=1e-5)


def tip_error(amplitude_m, friction_N=0.0):
    """Largest |x_c − x1| over the largest |x1|: full eq. 1-4 vs the reduced element,
    for a 5 kHz sinusoidal differential stroke."""
    piezo, g = H.equivalent()
    mp, kp, dp, g = float(piezo.Mp), float(piezo.Kp), float(piezo.Dp), float(g)
    w = 2 * np.pi * 5000.0

    def gamma(t):
        return amplitude_m * np.sin(w * t), amplitude_m * w * np.cos(w * t)

    full = solve_ivp(lambda t, s: hemisphere_rates(H, s, *gamma(t), friction_N),
                     (0, 1e-3), [float(H.rest_heave()), 0, 0, 0], max_step=2e-6,
                     rtol=1e-10, atol=1e-16, dense_output=True)
    red = solve_ivp(lambda t, s: [s[1], (kp * (g * gamma(t)[0] - s[0]) - dp * s[1]
                                         - friction_N) / mp],
                    (0, 1e-3), [0.0, 0.0], max_step=2e-6, rtol=1e-10, atol=1e-18,
                    dense_output=True)
    t = np.linspace(0, 1e-3, 1001)
    x_c = float(H.R) * np.sin(full.sol(t)[2])
    x1 = red.sol(t)[0]
    return np.max(np.abs(x_c - x1)) / np.max(np.abs(x1))


def test_lever_is_radius_over_column_spacing():
    assert float(H.lever()) == pytest.approx(0.5 / 0.8, rel=1e-6)


def test_small_tilt_reduction_matches_the_full_equations():
    assert tip_error(1e-6) < 1e-4  # tilt ~1 mrad
    assert tip_error(1e-6, friction_N=1e-3) < 1e-4  # the friction arm R − a maps to F_f
    # The reduction is first order in the tilt: at 0.14 rad it is off by ~10 %.
    assert 0.03 < tip_error(100e-6) < 0.3


def test_hemisphere_drives_a_stick_slip_runner():
    """A hemisphere sized to the paper's piezo element (I_a and C chosen so that Mp and
    Kp are Lu's) moves the runner as Lu's element does with a stroke scaled by R/(2r)."""
    import equinox as eqx

    base = ss.lu2015_slc1720()
    arm = 0.5e-3 * (0.5e-3 - 0.1875e-3)
    h = TiltingHemisphere(m_a=1.0e-6, I_a=float(base.piezo.Mp) * arm, R=0.5e-3, a=0.1875e-3,
                          r=0.4e-3, C=float(base.piezo.Kp) * arm / (2 * 0.4e-3**2),
                          D=float(base.piezo.Dp) * arm / (2 * 0.4e-3**2))
    act = with_hemisphere(base, h)
    assert float(act.piezo.Mp) == pytest.approx(float(base.piezo.Mp), rel=1e-9)
    assert float(act.piezo.Kp) == pytest.approx(float(base.piezo.Kp), rel=1e-9)
    assert float(act.piezo.Dp) == pytest.approx(float(base.piezo.Dp), rel=1e-9)
    g = float(h.lever())
    t, u = ss.sawtooth(60.0, 200.0, duration_s=0.02)
    drive = ss.DriveContext.make(amplitude=60.0, frequency=200.0)
    q = np.asarray(ss.simulate(act, u, dt=t[1] - t[0], drive=drive))
    scaled = eqx.tree_at(lambda a: a.hysteresis.weights, base, base.hysteresis.weights * g)
    np.testing.assert_allclose(q, np.asarray(ss.simulate(scaled, u, dt=t[1] - t[0],
                                                         drive=drive)), rtol=1e-9, atol=1e-15)
    full = np.asarray(ss.simulate(base, u, dt=t[1] - t[0], drive=drive))
    per = 125
    step, step_full = q[-1] - q[-1 - per], full[-1] - full[-1 - per]
    assert 10e-9 < step < step_full  # it steps, less than with the full stroke (g < 1)
