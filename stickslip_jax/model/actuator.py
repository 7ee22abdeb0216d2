"""The actuator: components composed into one vector field and one output.

The integrated state is one flat vector (the scan and sub-step loops carry one
array, and one XLA fusion computes the whole derivative, so shared terms such as
the friction law are computed once per stage, not once per state component):

    y = [x1, v1, x2, v2, z, input-stage states..., extension states...]

The hysteresis memory ``p`` (play-operator states [V]) is not integrated but
committed once per sub-step (docs/model.md "State and input").
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from .base import (
    AbstractExtension,
    AbstractFriction,
    AbstractHysteresis,
    AbstractInputStage,
    AbstractOutputMap,
    CoreState,
    DriveContext,
)
from .piezo import PiezoElement
from .slider import Slider
from .stages import IdentityInput, IdentityOutput

N_CORE = 5  # x1, v1, x2, v2, z


class Actuator(eqx.Module):
    """A piezo stick-slip actuator: piezo element, hysteresis, slider, friction, slots.

    Attributes
    ----------
    piezo: the piezo element (Mp, Dp, Kp, Kact2·N).
    hysteresis: voltage → free stroke Γ [m] (Prandtl-Ishlinskii by default).
    slider: the runner (Ms, Ds, external force, load spring).
    friction: the contact law (elasto-plastic by default, Stribeck, LuGre, ...).
    input_stage: recorded command → piezo voltage (identity by default).
    extensions: extra physics with their own states and additive terms (none by default).
    output_map: q → what the sensor reports, over whole traces (identity by default).
    """

    piezo: PiezoElement
    hysteresis: AbstractHysteresis
    slider: Slider
    friction: AbstractFriction
    input_stage: AbstractInputStage = IdentityInput()
    extensions: tuple[AbstractExtension, ...] = ()
    output_map: AbstractOutputMap = IdentityOutput()

    # ---- physics ----------------------------------------------------------------
    @property
    def n_states(self) -> int:
        """Length of the integrated state vector ``y``."""
        return N_CORE + self.input_stage.n_states + sum(e.n_states for e in self.extensions)

    def _slots(self, y):
        """Input-stage states and the list of extension states, as views of ``y``."""
        start = N_CORE + self.input_stage.n_states
        stage = y[N_CORE:start]
        ext = []
        for e in self.extensions:
            ext.append(y[start : start + e.n_states])
            start += e.n_states
        return stage, ext

    def piezo_voltage(self, y, u_command):
        """Voltage reaching the piezo [V] in state ``y`` under command ``u_command``."""
        if self.input_stage.n_states == 0:
            return self.input_stage.voltage(y[N_CORE:N_CORE], u_command)
        return self.input_stage.voltage(self._slots(y)[0], u_command)

    @property
    def stroke_follows_command(self) -> bool:
        """True when the free stroke depends on the command voltage alone.

        Then the simulator may evaluate the hysteresis along each sample interval in
        one vectorised call instead of once per Runge-Kutta stage (same numbers).
        """
        return self.input_stage.is_identity

    def free_stroke(self, y, memory, u_command):
        """Free stroke Γ [m] in state ``y`` for command ``u_command`` [V] and ``memory``."""
        return self.hysteresis.output(memory, self.piezo_voltage(y, u_command))

    def _core_and_terms(self, y, u_command, stroke, drive: DriveContext):
        x1, v1, x2, v2, z = y[0], y[1], y[2], y[3], y[4]
        u = self.piezo_voltage(y, u_command)
        xdot = v1 - v2
        zdot = self.friction.z_rate(z, xdot, drive)
        ff = self.friction.force(z, zdot, xdot, drive)
        core = CoreState(x1, v1, x2, v2, z, ff, u, stroke, self.piezo.push(x1, v1, stroke))
        if not self.extensions:
            return core, zdot, []
        _, ext = self._slots(y)
        terms = [e.terms(s, core, drive) for e, s in zip(self.extensions, ext, strict=True)]
        return core, zdot, terms

    def vector_field(self, y, u_command, stroke, drive: DriveContext):
        """dy/dt at command ``u_command`` [V] (same layout as ``y``).

        ``stroke`` is the hysteresis output Γ [m] at this instant (see
        :meth:`free_stroke`); extensions may add to it.
        """
        core, zdot, terms = self._core_and_terms(y, u_command, stroke, drive)
        ff = core.ff
        f_piezo = f_slider = 0.0
        for t in terms:
            stroke = stroke + t.stroke
            ff = ff + t.friction
            f_piezo = f_piezo + t.force_piezo
            f_slider = f_slider + t.force_slider
        a1 = self.piezo.acceleration(core.x1, core.v1, stroke, ff, f_piezo)
        a2 = self.slider.acceleration(core.x2, core.v2, ff, f_slider)
        scalars = [core.v1, a1, core.v2, a2, zdot]
        if self.n_states > N_CORE:
            stage, ext = self._slots(y)
            if self.input_stage.n_states:
                scalars += list(self.input_stage.rate(stage, u_command))
            for e, s in zip(self.extensions, ext, strict=True):
                if e.n_states:
                    scalars += list(e.rate(s, core, drive))
        # One stack of scalars (not a concatenation of vectors): XLA on CPU then fuses
        # the whole derivative into one kernel (measured 4x faster under jacfwd).
        return jnp.stack(scalars)

    def project(self, y, drive: DriveContext):
        """Saturate the friction state after a sub-step (|z| ≤ |z_ss|), and let each
        extension project its own states (extra contacts saturate theirs)."""
        xdot = y[1] - y[3]
        y = y.at[4].set(self.friction.project(y[4], xdot, drive))
        if self.extensions:
            start = N_CORE + self.input_stage.n_states
            for e in self.extensions:
                if e.n_states and type(e).project is not AbstractExtension.project:
                    part = e.project(y[start : start + e.n_states], xdot, drive)
                    y = y.at[start : start + e.n_states].set(part)
                start += e.n_states
        return y

    def velocity_kink(self, y, drive: DriveContext):
        """How sharply the vector field bends where the relative velocity ``v1 − v2``
        changes sign, in state ``y`` [-]: the friction law's kink at its strain, plus
        any extension's (extra contacts). 0 where the field is smooth in ``v1 − v2``."""
        kink = self.friction.velocity_kink(y[4], drive)
        if self.extensions:
            start = N_CORE + self.input_stage.n_states
            for e in self.extensions:
                if e.n_states and type(e).velocity_kink is not AbstractExtension.velocity_kink:
                    kink = kink + e.velocity_kink(y[start : start + e.n_states], drive)
                start += e.n_states
        return kink

    def switches(self, y, ydot, drive: DriveContext):
        """Switching functions of the contact and their time derivatives, ``(g, ġ)``.

        ``g[0] = ẋ = v1 − v2`` [m/s] (a slip reversal where the friction law bends,
        :meth:`velocity_kink`), then ``|z| − z_s`` [m] for each strain switch ``z_s`` of
        the law (:meth:`AbstractFriction.strain_switches`). ``ydot`` is ``dy/dt`` at
        ``y``. The simulator locates sign changes of these inside a sub-step.
        """
        z = y[4]
        g = [y[1] - y[3]]
        rate = [ydot[1] - ydot[3]]
        for z_s in self.friction.strain_switches(drive):
            g.append(jnp.abs(z) - z_s)
            rate.append(jnp.sign(z) * ydot[4])
        return jnp.stack(g), jnp.stack(rate)

    def switch_active(self, y, drive: DriveContext):
        """Which of :meth:`switches` change the vector field's form at ``y`` [bool]:
        the reversal where the law bends there, a strain switch where ``z`` and ``ẋ``
        share a sign (elsewhere α is 0 on both sides)."""
        active = [self.velocity_kink(y, drive) > 0]
        same = (y[1] - y[3]) * y[4] > 0
        active += [same for _ in self.friction.strain_switches(drive)]
        return jnp.stack(active)

    def commit_memory(self, y, memory, u_command):
        """Hysteresis memory once the piezo voltage has reached its end-of-step value."""
        return self.hysteresis.update(memory, self.piezo_voltage(y, u_command))

    def output(self, y, u_command, stroke, drive: DriveContext):
        """Model output q = x1 + x2 (+ extension outputs) [m], before the output map."""
        q = y[0] + y[2]
        if self.extensions:
            *_, terms = self._core_and_terms(y, u_command, stroke, drive)
            for t in terms:
                q = q + t.output
        return q

    def initial_state(self, u0, drive: DriveContext):
        """Rest under ``u0`` [V] (docs/model.md): plays as if risen from 0, static equilibrium.

        ``v1 = v2 = 0``, ``x2 = 0``, ``z`` carries ``−F_ext``, and
        ``x1 = Γ[U](0) − (Kact2·N − F_ext)/Kp``. Returns ``(state, memory)``.
        """
        u0 = jnp.asarray(u0, dtype=float)
        stage0 = self.input_stage.initial_state(u0)
        u_piezo = self.input_stage.voltage(stage0, u0)
        memory = self.hysteresis.initial_memory(u_piezo)
        stroke = self.hysteresis.output(memory, u_piezo)
        f_ext = self.slider.F_ext
        z0 = self.friction.z_at_rest(-f_ext, drive) + jnp.zeros_like(u0)
        x1 = stroke - (self.piezo.preload_force - f_ext) / self.piezo.Kp
        zero = jnp.zeros_like(u0)
        parts = [jnp.stack([x1, zero, zero, zero, z0]), stage0]
        parts += [e.initial_state(u_piezo) for e in self.extensions]
        return jnp.concatenate(parts), memory

    def with_extension(self, extension: AbstractExtension) -> Actuator:
        """A copy with one more extension appended."""
        return eqx.tree_at(lambda a: a.extensions, self, self.extensions + (extension,))
