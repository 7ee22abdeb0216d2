"""Documented default parameter sets.

``lu2015_slc1720()`` — the paper's actuator (SmarAct SLC-1720-S-HV, Y axis).

What it keeps from Lu et al. 2015 §IV-B.1, read in SI units: Mp = 2.47e-4 kg,
Dp = 15.6125 N·s/m, Kp = 2.62e6 N/m, Ms = 0.0247 kg, Ds = 64.9651 N·s/m,
rho0 = 3.517e5 N/m, rho1 = 0, zba_ratio = 0.667. The paper prints "Ns/µm" and
"N/µm"; read per micrometre, Kp/Mp would put the piezo mode near 16 MHz, so the
values only make sense in SI (N/m, N·s/m), which is how they are read here.

What it does not keep: Kact2 = 1200 cannot be read in SI (1200·N/Kp would be about
0.5 mm of static shift per newton of preload), so Kact2 = 0 (it only shifts the
static equilibrium). The PI weights and z_ba are not printed (Fig. 7 and Fig. 8 are
plots); they are chosen here so that the actuator scans at 20 V and steps at 40 and
60 V for 50-500 Hz as the paper reports, with a longer forward than backward step
(the asymmetry of Fig. 8/10): 35 plays, thresholds over 0-60 V crowded near 0, a
linear part of 20 nm/V and 5 nm/V spread over the plays; z_ba = 0.40 µm forward,
0.45 µm backward.

The table/spectrum disagreement (docs/model.md): the printed table gives linearised modes
at about 565 Hz and 17 kHz and an antiresonance of q = x1 + x2 at about 850 Hz, not
the printed 595 Hz, 1633 Hz and 725 Hz. No positive parameter set of this model can
put an antiresonance between two resonances at those three frequencies (see
:func:`stickslip_jax.linear.spectrum_consistency`). This profile follows the table
(the values the paper identified and simulated with) and states the disagreement in
``tests/test_linear.py`` rather than inventing masses to fit a spectrum the model
cannot produce.
"""

from __future__ import annotations

import numpy as np

from .actuator import Actuator
from .friction import DEFAULT_ZBA_RATIO, ElastoPlastic
from .hysteresis import PrandtlIshlinskii, default_thresholds
from .piezo import PiezoElement
from .slider import Slider

LU2015_TABLE = {
    "Mp": 2.47e-4, "Dp": 15.6125, "Kp": 2.62e6, "Ms": 0.0247, "Ds": 64.9651,
    "rho0": 3.517e5, "rho1": 0.0, "Kact2": 1200.0,
}
"""The identified values as printed in Lu et al. 2015 §IV-B.1 (read in SI)."""


def lu2015_pi(n: int = 35, u_max: float = 60.0) -> PrandtlIshlinskii:
    """The default hysteresis: ``n`` plays over 0..``u_max`` V, 25 nm/V in all."""
    r = default_thresholds(n, u_max)
    tail = np.exp(-r[1:] / 15.0)
    w = np.r_[2.0e-8, 0.5e-8 * tail / tail.sum()]
    return PrandtlIshlinskii(r, w)


def lu2015_slc1720() -> Actuator:
    """The default profile: the paper's SLC-1720-S-HV Y axis (see module docstring)."""
    t = LU2015_TABLE
    return Actuator(
        piezo=PiezoElement(t["Mp"], t["Dp"], t["Kp"], Kact2=0.0, N=0.0),
        hysteresis=lu2015_pi(),
        slider=Slider(t["Ms"], t["Ds"]),
        friction=ElastoPlastic(t["rho0"], 0.40e-6, 0.45e-6, zba_ratio=DEFAULT_ZBA_RATIO,
                               rho1=t["rho1"]),
    )


DEFAULT_PROFILE = "lu2015_slc1720"
PROFILES = {"lu2015_slc1720": lu2015_slc1720}
