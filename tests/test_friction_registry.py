"""A friction law is one final class in one file: a toy law defined here, and only here,
is read from a parameter file, simulated, written back and fitted by the library's own
machinery, found through the registry (stickslip_jax.model.registry)."""

import json

import jax.numpy as jnp
import numpy as np
import pytest
from jaxtyping import Array, Float

import stickslip_jax as ss
from stickslip_jax.identify.dataset import Dataset
from stickslip_jax.identify.parameters import (
    FITTABLE,
    SCALE_INVARIANT,
    ParameterMap,
    fittable_names,
    scale_invariant_names,
)
from stickslip_jax.identify.residuals import TraceResiduals
from stickslip_jax.identify.solve import solve_least_squares
from stickslip_jax.identify.step_names import (
    DYNAMICS,
    breakaway_names,
    dynamics_names,
    friction_names,
)
from stickslip_jax.model.contacts import split_contact
from stickslip_jax.params import describe_parameters

TOY = "linear-bristle-coulomb"


@ss.register_friction_law(TOY)
class LinearBristleCoulomb(ss.AbstractFriction):
    """Jenkins element: a linear bristle of stiffness ``k`` [N/m] in series with a
    Coulomb slider of level ``F_c`` [N]. ``ż = ẋ`` while the bristle carries less than
    ``F_c``, ``ż = 0`` while it slides (``|z| = F_c/k`` with ``z`` and ``ẋ`` of one sign);
    ``Ff = k·z``."""

    parameters = (
        ss.LawParameter("k", "N/m", "bristle stiffness", required=True, lower=0.0,
                        lower_open=True, step="dynamics", mass_scaled=True, stiffness=True,
                        with_normal_force=True),
        ss.LawParameter("F_c", "N", "Coulomb force", required=True, lower=0.0,
                        lower_open=True, step="friction", mass_scaled=True,
                        with_normal_force=True),
    )

    k: Float[Array, ""]
    F_c: Float[Array, ""]

    @classmethod
    def from_params(cls, values):
        return cls(**values)

    def z_rate(self, z, xdot, drive):
        sliding = (xdot * z > 0) & (jnp.abs(z) >= self.F_c / self.k)
        return jnp.where(sliding, 0.0, xdot)

    def force(self, z, zdot, xdot, drive):
        return self.k * z

    def project(self, z, xdot, drive):
        z_max = self.F_c / self.k
        return jnp.clip(z, -z_max, z_max)

    def z_at_rest(self, force, drive):
        return force / self.k

    def stiffness(self, drive):
        return self.k

    def coulomb_force(self, drive):
        return self.F_c

    def strain_switches(self, drive):
        return (self.F_c / self.k,)  # ż drops from ẋ to 0 where the bristle saturates

    def velocity_kink(self, z, drive):
        # Saturated: ∂ż/∂ẋ is 0 on the side that keeps sliding, 1 on the other.
        return jnp.where(jnp.abs(z) >= self.F_c / self.k, 1.0, 0.0)


K, F_C = 3.517e5, 0.21


@pytest.fixture(autouse=True, scope="module")
def _unregister_afterwards():
    yield
    ss.FRICTION_LAWS.pop(TOY, None)


@pytest.fixture(scope="module")
def toy_params():
    params = ss.params_from_actuator(ss.lu2015_slc1720())
    law = {p.name for p in ss.ElastoPlastic.parameters}
    params = {k: v for k, v in params.items() if k not in law}
    return {**params, "friction": TOY, "k": K, "F_c": F_C}


def test_the_registry_finds_the_toy_law_and_its_parameters(toy_params):
    assert ss.FRICTION_LAWS[TOY] is LinearBristleCoulomb
    assert list(ss.FRICTION_LAWS)[:3] == ["elastoplastic", "lugre", "ceim"]
    act = ss.actuator_from_params(toy_params)
    assert isinstance(act.friction, LinearBristleCoulomb)
    assert float(act.friction.k) == K and float(act.friction.F_c) == F_C
    text = "\n".join(describe_parameters())
    assert f"friction '{TOY}':" in text and "Coulomb force [N] (required" in text
    # The bounds, the required names and the unknown names come from the records.
    with pytest.raises(ss.ParameterError, match="'F_c' must be positive"):
        ss.actuator_from_params({**toy_params, "F_c": -0.1}, source="P.json")
    with pytest.raises(ss.ParameterError, match="missing required parameter.*F_c"):
        ss.actuator_from_params({k: v for k, v in toy_params.items() if k != "F_c"})
    with pytest.raises(ss.ParameterError, match="'rho0'.*allowed names.*F_c"):
        ss.actuator_from_params({**toy_params, "rho0": 1.0})
    # The identification knows which step fits what, and what sets the scale.
    assert dynamics_names(act, fix={"Ms": 0.02}) == ["Mp", "Dp", "Kp", "Ds", "k"]
    assert friction_names(act) == ["F_c"]
    assert breakaway_names(act, [ss.DriveSpec("step", 40.0).recording()]) == []
    assert fittable_names(act) == ("Mp", "Dp", "Kp", "Ms", "Ds", "k", "F_c", "pi_weights")
    assert scale_invariant_names(act)[-2:] == ("k", "F_c")
    # A multi-contact runner splits the quantities proportional to the normal force.
    half = split_contact(act.friction, 0.5)
    assert float(half.k) == K / 2 and float(half.F_c) == F_C / 2


def test_the_toy_law_writes_and_reads_back_exactly(toy_params, tmp_path):
    act = ss.actuator_from_params(toy_params)
    path = ss.save_params(act, tmp_path / "toy.json")
    data = json.loads(path.read_text())
    assert data["friction"] == TOY and data["k"] == K and data["F_c"] == F_C
    assert ss.params_from_actuator(ss.load_params(path)) == data == ss.params_from_actuator(act)


def test_the_toy_law_steps_and_slides_at_its_coulomb_level(toy_params):
    act = ss.actuator_from_params(toy_params)
    t, u = ss.sawtooth(60.0, 500.0, duration_s=0.01)
    drive = ss.DriveContext.make(amplitude=60.0, frequency=500.0)
    tr = ss.simulate_states(act, u, dt=t[1] - t[0], drive=drive)
    q, z, ff = (np.asarray(x) for x in (tr.q, tr.z, tr.friction))
    assert np.all(np.isfinite(q))
    assert np.max(np.abs(z)) <= F_C / K * (1 + 1e-12)
    np.testing.assert_allclose(ff, K * z, rtol=1e-12, atol=0)
    assert np.max(np.abs(ff)) > 0.999 * F_C  # it slides, at the Coulomb level
    per = int(round(25_000 / 500))
    steps = q[per::per][1:] - q[per::per][:-1]
    assert np.all(steps > 100e-9), steps  # a stepping drive: ~0.1 µm or more per period


def test_identification_recovers_the_toy_coulomb_force(toy_params):
    """Data at the reference stepping (16x finer than the fit's: no inverse crime), 1 nm
    noise; F_c fitted from 20 % off with the library's parameter map, residuals and
    Levenberg-Marquardt, its transform (log: positive) from the law's record."""
    truth = ss.actuator_from_params(toy_params)
    specs = [ss.DriveSpec("sawtooth", 60.0, 500.0, d, 0.01) for d in ("forward", "backward")]
    recordings = ss.simulate_set(truth, specs, noise_m=1e-9, seed=3)
    start = ss.actuator_from_params({**toy_params, "F_c": 1.2 * F_C})
    pmap = ParameterMap.make(start, ["F_c"])
    assert pmap.free[0].kind == "log"
    res = TraceResiduals.make(pmap, Dataset.from_recordings(recordings), w_steps=1.0)
    out = solve_least_squares(res, pmap.zeros(), max_steps=30)
    fitted = float(pmap.physical(out.theta)["F_c"])
    print(f"F_c: start {1.2 * F_C:g} N, fitted {fitted:.6g} N (truth {F_C:g} N) in "
          f"{out.iterations} steps")
    assert out.converged
    assert abs(fitted / F_C - 1) < 0.01, fitted


# ------------------------------------------------------- the built-in laws, unchanged
def test_the_paper_law_keeps_its_names_and_its_zba_ratio_default():
    assert ss.DEFAULT_ZBA_RATIO == 0.667  # Lu 2015 §IV-B.3
    assert float(ss.ElastoPlastic(1.0, 1e-6).zba_ratio) == ss.DEFAULT_ZBA_RATIO
    assert float(ss.lu2015_slc1720().friction.zba_ratio) == ss.DEFAULT_ZBA_RATIO
    assert FITTABLE == ("Mp", "Dp", "Kp", "Ms", "Ds", "rho0", "rho1", "rho2", "z_ba_forward",
                        "z_ba_backward", "zba_ratio", "pi_weights")
    assert SCALE_INVARIANT == ("Mp", "Dp", "Kp", "Ms", "Ds", "rho0", "rho1", "rho2")
    act = ss.lu2015_slc1720()
    assert dynamics_names(act) == list(DYNAMICS)
    assert dynamics_names(act, fix={"Ms": 1.0}, also_fit=["rho1"]) == \
        ["Mp", "Dp", "Kp", "Ds", "rho0", "rho1"]
    assert friction_names(act) == ["z_ba_forward", "z_ba_backward"]
    assert friction_names(act, also_fit=["zba_ratio"]) == \
        ["z_ba_forward", "z_ba_backward", "zba_ratio"]
    step = [ss.DriveSpec("step", 40.0).recording()]
    assert breakaway_names(act, step) == ["z_ba_forward"]


@pytest.mark.parametrize("name", ["identification/truth.json", "reference/params.json"])
def test_fixture_files_read_and_write_as_before(fixtures_dir, name):
    path = fixtures_dir / name
    data = json.loads(path.read_text())
    written = ss.params_from_actuator(ss.load_params(path))
    # Every value as in the file, and the defaults of what the file omits; the
    # shorthand z_ba (equal to z_ba_forward there) is read but not written back.
    assert data.get("z_ba", data["z_ba_forward"]) == data["z_ba_forward"]
    data.pop("z_ba", None)
    assert {k: written[k] for k in data} == data
    assert {k: v for k, v in written.items() if k not in data} == \
        {k: 0.0 for k in ("F_ext", "k_load") if k not in data}


def test_the_default_profile_writes_the_documented_file(tmp_path):
    path = ss.save_params(ss.lu2015_slc1720(), tmp_path / "p.json")
    data = json.loads(path.read_text())
    assert list(data) == ["Mp", "Dp", "Kp", "Ms", "Ds", "Kact2", "N", "F_ext", "k_load",
                          "pi_thresholds", "pi_weights", "friction", "rho0", "rho1", "rho2",
                          "z_ba_forward", "z_ba_backward", "zba_ratio"]
    assert data["friction"] == "elastoplastic" and data["zba_ratio"] == 0.667
    assert data["z_ba_forward"] == 0.40e-6
    assert ss.params_from_actuator(ss.load_params(path)) == data
    stribeck = ss.actuator_from_params({**data, "stribeck_ratio": 1.5, "v_s": 1e-3})
    assert isinstance(stribeck.friction, ss.StribeckElastoPlastic)
    again = ss.params_from_actuator(stribeck)
    assert again["friction"] == "elastoplastic" and list(again)[-2:] == ["stribeck_ratio", "v_s"]
