"""The public API: every name in ``stickslip_jax.__all__`` exists and documents itself."""

import inspect

import stickslip_jax as ss


def test_every_public_name_exists_and_has_its_own_docstring():
    undocumented = []
    for name in ss.__all__:
        obj = getattr(ss, name)  # AttributeError if a name is listed but not exported
        if inspect.isclass(obj):
            doc = obj.__dict__.get("__doc__")
        elif inspect.isfunction(obj):
            doc = obj.__doc__
        else:
            continue
        if not doc or len(doc.strip()) < 20:
            undocumented.append(name)
    assert not undocumented, undocumented
    assert len(set(ss.__all__)) == len(ss.__all__)


def test_trajectory_matches_simulate():
    import numpy as np

    act = ss.lu2015_slc1720()
    t, u = ss.sawtooth(60.0, 500.0, duration_s=0.006)
    drive = ss.DriveContext.make(amplitude=60.0, frequency=500.0)
    q = np.asarray(ss.simulate(act, u, dt=t[1] - t[0], drive=drive))
    tr = ss.simulate_states(act, u, dt=t[1] - t[0], drive=drive)
    np.testing.assert_array_equal(np.asarray(tr.q), q)
    np.testing.assert_allclose(np.asarray(tr.x1 + tr.x2), q, rtol=0, atol=1e-15)
    # Elasto-plastic with rho1 = rho2 = 0: the friction force is rho0 * z.
    np.testing.assert_allclose(np.asarray(tr.friction), float(act.friction.rho0) * np.asarray(tr.z))
    # |z| never exceeds |z_ss| (the saturation every sub-step).
    zss = float(act.friction.zss_magnitude(0.0, drive))
    assert np.max(np.abs(np.asarray(tr.z))) <= zss * (1 + 1e-12)
    # This drive slips (|z| reaches the transition zone above z_ba; the samples may
    # miss the sub-sample peak at |z_ss|); a 10 V drive only sticks.
    assert np.max(np.abs(np.asarray(tr.z))) > 0.9 * zss
    t, u = ss.sawtooth(10.0, 500.0, duration_s=0.006)
    small = ss.simulate_states(act, u, dt=t[1] - t[0], drive=drive)
    assert np.max(np.abs(np.asarray(small.z))) < float(act.friction.z_ba(drive))


def test_the_command_line_starts_without_the_heavy_optional_imports():
    # scipy.stats (one χ² tail in the diagnosis), scipy.signal (it imports scipy.stats)
    # and optimistix (the z_ba surface's solver) cost about 0.7 s to import; the
    # command line must not pay that at start, nor identify's PSD figures.
    import subprocess
    import sys

    code = ("import sys, numpy as np, stickslip_jax.cli.main\n"
            "from stickslip_jax.identify.figures import display_psd\n"
            "display_psd(np.sin(np.arange(4000) / 7.0), 4e-5, period_samples=44.0)\n"
            "print(sorted(m for m in ('scipy.stats', 'scipy.signal', 'optimistix')\n"
            "             if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "[]", out.stdout + out.stderr
