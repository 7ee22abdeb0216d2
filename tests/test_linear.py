"""The linearised stick dynamics, the paper's table/spectrum disagreement, and a check
of the linear analysis against the nonlinear simulator.

docs/model.md: the printed table of Lu 2015 (read in SI) puts the modes at about
520-560 Hz (damped/undamped) and 17 kHz and the q = x1 + x2 antiresonance at
sqrt(2·rho0/Ms)/(2π) ≈ 849 Hz, not at the printed 595 Hz, 1633 Hz and 725 Hz; and no
positive undamped chain has that printed spectrum at all. Measured here:

    undamped modes  563.87 Hz, 17458.4 Hz
    damped modes    523.32 Hz (ζ = 0.372), 16717.9 Hz (ζ = 0.288)
    q antiresonance 849.32 Hz undamped, 823.13 Hz damped
    |q/Γ| peak      394.8 Hz (heavy damping + the zero pull the peak below the mode)
    spectrum_consistency(595, 1633, 725): rho0/Mp = −3.294e7 1/s² (impossible);
        the q antiresonance must lie in (√2·595, √2·1633) = (841.5, 2309.4) Hz.
"""

from __future__ import annotations

import math

import equinox as eqx
import numpy as np
import pytest

import stickslip_jax as ss
from stickslip_jax.linear import (
    frequency_response,
    spectrum_consistency,
    stick_chain,
    stick_modes,
)

FS = 25_000.0
DT = 1.0 / FS


@pytest.fixture(scope="module")
def actuator():
    return ss.lu2015_slc1720()


def test_default_profile_modes_are_not_the_printed_spectrum(actuator):
    m = stick_modes(actuator)
    t = ss.LU2015_TABLE
    # Values found (see module docstring), to 0.1 %.
    np.testing.assert_allclose(m.undamped_Hz, [563.8655, 17458.41], rtol=1e-3)
    np.testing.assert_allclose(m.damped_Hz, [523.3196, 16717.92], rtol=1e-3)
    np.testing.assert_allclose(m.damping_ratio, [0.3724, 0.2881], rtol=2e-3)
    # docs/model.md: first mode ~520-560 Hz (damped/undamped), second ~17 kHz.
    assert 520.0 < m.damped_Hz[0] < m.undamped_Hz[0] < 600.0
    assert m.undamped_Hz[1] > 10_000.0 and m.damped_Hz[1] > 10_000.0
    # The undamped q zero is sqrt(2·rho0/Ms)/(2π) ≈ 849 Hz.
    fa = math.sqrt(2 * t["rho0"] / t["Ms"]) / (2 * math.pi)
    assert m.antiresonance_undamped_Hz == pytest.approx(fa, rel=1e-12)
    assert m.antiresonance_undamped_Hz == pytest.approx(849.32, abs=0.05)
    assert m.antiresonance_damped_Hz == pytest.approx(823.13, abs=0.05)
    # ... and none of them is the printed spectrum (595 Hz, 1633 Hz, 725 Hz).
    assert abs(m.undamped_Hz[0] - 595.0) > 25.0 and abs(m.damped_Hz[0] - 595.0) > 60.0
    assert np.all(np.abs(m.undamped_Hz - 1633.0) > 500.0)
    assert abs(m.antiresonance_undamped_Hz - 725.0) > 100.0
    # The antiresonance sits above the first mode, not between 595 and 1633 by chance:
    # for this chain it must exceed √2 times the first undamped mode.
    assert m.antiresonance_undamped_Hz > math.sqrt(2) * m.undamped_Hz[0]


def test_undamped_modes_match_the_closed_form_chain(actuator):
    # The eigenvalue route (stick_modes) and the closed-form inversion
    # (spectrum_consistency) are independent: feeding the computed spectrum back
    # must recover the table's ratios exactly.
    m = stick_modes(actuator)
    t = ss.LU2015_TABLE
    r = spectrum_consistency(m.undamped_Hz[0], m.undamped_Hz[1], m.antiresonance_undamped_Hz)
    assert r.feasible
    assert r.rho0_per_Ms == pytest.approx(t["rho0"] / t["Ms"], rel=1e-9)
    assert r.Kp_per_Mp == pytest.approx(t["Kp"] / t["Mp"], rel=1e-9)
    assert r.rho0_per_Mp == pytest.approx(t["rho0"] / t["Mp"], rel=1e-9)
    assert r.Mp_per_Ms == pytest.approx(t["Mp"] / t["Ms"], rel=1e-9)
    assert r.Kp_per_Ms == pytest.approx(t["Kp"] / t["Ms"], rel=1e-9)


def test_printed_spectrum_is_impossible():
    r = spectrum_consistency(595.0, 1633.0, 725.0)
    assert not r.feasible
    assert "impossible" in r.message
    # Required per-unit-mass values (ω = 2πf): negative contact stiffness per Mp,
    # hence a negative mass ratio.
    w1, w2, wa = (2 * math.pi * np.array([595.0, 1633.0, 725.0])) ** 2
    assert r.rho0_per_Ms == pytest.approx(wa / 2, rel=1e-12)
    assert r.Kp_per_Mp == pytest.approx(2 * w1 * w2 / wa, rel=1e-12)
    assert r.rho0_per_Mp == pytest.approx(-3.2937e7, rel=1e-4)
    assert r.rho0_per_Mp < 0 and r.Mp_per_Ms < 0
    lo, hi = r.fa_range_Hz
    assert lo == pytest.approx(841.457, abs=1e-3) and hi == pytest.approx(2309.41, abs=1e-2)
    assert not (lo < 725.0 < hi)
    # The feasibility boundary is exactly √2·f1: just inside it is feasible.
    assert spectrum_consistency(595.0, 1633.0, lo * 1.001).feasible
    assert not spectrum_consistency(595.0, 1633.0, lo * 0.999).feasible
    assert not spectrum_consistency(595.0, 1633.0, hi * 1.001).feasible


def test_frequency_response_limits(actuator):
    t = ss.LU2015_TABLE
    h0 = complex(frequency_response(actuator, 0.0))
    # In stick the slider follows the tip: x1 = x2 = Γ at DC, so q/Γ = 2.
    assert h0 == pytest.approx(2.0, abs=1e-12)
    assert complex(frequency_response(actuator, 0.0, output="x1")) == pytest.approx(1.0)
    assert complex(frequency_response(actuator, 0.0, output="x2")) == pytest.approx(1.0)
    # High frequency: q/Γ → −Kp/(Mp·ω²) (piezo mass line).
    f = 1e6
    h = complex(frequency_response(actuator, f))
    assert h.real == pytest.approx(-t["Kp"] / (t["Mp"] * (2 * math.pi * f) ** 2), rel=0.02)
    # Undamped copy: |q/Γ| vanishes at the antiresonance and blows up at the modes.
    undamped = eqx.tree_at(lambda a: (a.piezo.Dp, a.slider.Ds), actuator, (0.0, 0.0))
    m = stick_modes(undamped)
    assert abs(complex(frequency_response(undamped, m.antiresonance_undamped_Hz))) < 1e-9
    for fm in m.undamped_Hz:
        assert abs(complex(frequency_response(undamped, fm * (1 + 1e-9)))) > 1e6
    # A load spring raises the zero to sqrt((2·rho0 + k_load)/Ms)/(2π).
    loaded = eqx.tree_at(lambda a: a.slider.k_load, actuator, 1e5)
    fa = math.sqrt((2 * t["rho0"] + 1e5) / t["Ms"]) / (2 * math.pi)
    assert stick_modes(loaded).antiresonance_undamped_Hz == pytest.approx(fa, rel=1e-12)


def test_the_chains_numpy_response_is_frequency_response(actuator):
    """StickChain.response (the figures' numpy evaluation) is frequency_response's
    transfer function, whatever the output, for the default and a backward drive."""
    f = np.array([0.0, 37.0, 595.0, 725.0, 1633.0, 2.0e4])
    for drive in (None, ss.DriveContext.make(backward=True, amplitude=40.0, frequency=500.0)):
        chain = stick_chain(actuator, drive)
        for output in ("q", "x1", "x2"):
            ref = np.asarray(frequency_response(actuator, f, drive, output=output))
            got = chain.response(f, output)
            np.testing.assert_allclose(got, ref, rtol=1e-12)
            assert np.ptp(np.abs(ref)) > 0.1  # the frequencies span the chain's features
    with pytest.raises(ValueError, match="output"):
        chain.response(f, "x3")
    with pytest.raises(ValueError, match="output"):
        frequency_response(actuator, f, output="x3")


def test_contact_parameters_come_from_the_friction_law(actuator):
    ch = stick_chain(actuator)
    assert ch.kc == pytest.approx(3.517e5) and ch.cc == 0.0
    ep = eqx.tree_at(lambda a: (a.friction.rho1, a.friction.rho2), actuator, (3.0, 0.5))
    assert stick_chain(ep).cc == pytest.approx(3.5, rel=1e-12)
    lugre = eqx.tree_at(lambda a: a.friction, actuator,
                        ss.LuGre(2e5, 1.5, 0.25, 0.1, 0.12, 1e-3))
    ch = stick_chain(lugre)
    assert ch.kc == pytest.approx(2e5) and ch.cc == pytest.approx(1.75, rel=1e-12)
    # σ0 replaces ρ0 in the q zero.
    assert stick_modes(lugre).antiresonance_undamped_Hz == pytest.approx(
        math.sqrt(2 * 2e5 / 0.0247) / (2 * math.pi), rel=1e-12)


@pytest.fixture(scope="module")
def small_step(actuator):
    """A 0.5 V step (stick only; only the linear play is open below 0.59 V), 0.1 s."""
    _, u = ss.step(0.5, duration_s=0.1)
    light = eqx.tree_at(lambda a: (a.piezo.Dp, a.slider.Ds), actuator,
                        (actuator.piezo.Dp / 10, actuator.slider.Ds / 10))
    q = np.asarray(ss.simulate(actuator, u, dt=DT))
    q_light = np.asarray(ss.simulate(light, u, dt=DT))
    gamma = 0.5 * float(actuator.hysteresis.weights[0])
    assert float(actuator.hysteresis.thresholds[1]) > 0.5
    return q, q_light, light, gamma


def test_step_response_spectrum_matches_linear_transfer(actuator, small_step):
    q, _, _, gamma = small_step
    assert q[-1] / gamma == pytest.approx(2.0, abs=1e-9)   # settled, static gain 2
    # FFT of the sample differences of q over the stroke step: H(f)·sinc(f·dt),
    # delayed to the middle of the ramp (samples 49 → 50: the step is at 2 ms), less
    # the half sample by which q[k+1] − q[k] leads the rate it stands for.
    n = 2**16
    f = np.fft.rfftfreq(n, DT)
    delay = 2 * np.pi * f * (49.0 * DT)
    h_sim = np.fft.rfft(np.diff(q), n) / gamma * np.exp(1j * delay)
    h_lin = np.asarray(frequency_response(actuator, f)) * np.sinc(f * DT)
    band = (f > 20) & (f < 1000)
    err = np.abs(h_sim[band] / h_lin[band] - 1)
    assert err.max() < 0.01          # measured 0.006 (sampling/aliasing near 1 kHz)
    band = (f > 20) & (f < 2000)
    assert np.abs(np.abs(h_sim[band]) / np.abs(h_lin[band]) - 1).max() < 0.03  # 0.020
    # The simulated |q/Γ| peak is where the linear analysis puts it (394.8 Hz).
    peak_sim = f[band][np.argmax(np.abs(h_sim[band]))]
    peak_lin = f[band][np.argmax(np.abs(h_lin[band]))]
    assert peak_sim == pytest.approx(peak_lin, rel=0.01)
    assert peak_sim == pytest.approx(394.8, rel=0.01)


def test_step_ringing_is_the_first_damped_mode(actuator, small_step):
    q, _, _, gamma = small_step
    m = stick_modes(actuator)
    # After 0.6 ms the 17 kHz mode (decay 31600 1/s) is gone; the tail is one damped
    # oscillation. A two-tap linear prediction (Prony) gives its complex frequency.
    k0, k1 = 50 + 15, 50 + 200
    y = q[k0:k1] - 2 * gamma
    a = np.linalg.lstsq(np.c_[y[1:-1], y[:-2]], y[2:], rcond=None)[0]
    s = np.log(np.roots([1.0, -a[0], -a[1]]).astype(complex)) / DT
    f_d = np.abs(s.imag).max() / (2 * math.pi)
    sigma = -s.real.mean()
    assert f_d == pytest.approx(m.damped_Hz[0], rel=1e-4)        # measured 2e-9
    assert sigma == pytest.approx(m.damping_ratio[0] * m.natural_Hz[0] * 2 * math.pi,
                                  rel=1e-4)


def test_lightly_damped_psd_peak_is_the_first_damped_mode(small_step):
    _, q, light, gamma = small_step
    m = stick_modes(light)
    assert m.damping_ratio[0] == pytest.approx(0.0372, rel=0.01)
    n = 2**16
    f = np.fft.rfftfreq(n, DT)
    # The ringing has decayed (e^-13) by the end of the 0.1 s trace: no window needed.
    psd = np.abs(np.fft.rfft(np.diff(q), n)) ** 2
    band = (f > 50) & (f < 5000)
    peak = f[band][np.argmax(psd[band])]
    assert peak == pytest.approx(m.damped_Hz[0], rel=0.01)      # 561.9 vs 563.5 Hz
    # and the antiresonance: the PSD dip above the first mode, at the q zero.
    band = (f > peak) & (f < 5000)
    dip = f[band][np.argmin(psd[band])]
    assert dip == pytest.approx(m.antiresonance_damped_Hz, rel=0.01)   # 851.1 vs 849.1 Hz
    assert dip == pytest.approx(m.antiresonance_undamped_Hz, rel=0.01)
