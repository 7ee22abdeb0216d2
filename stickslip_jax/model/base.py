"""Abstract interfaces of the actuator's components.

Every component is an equinox Module: its array fields are the (differentiable)
parameters, its static fields are structure. A new friction law, hysteresis law or
model extension is one new final class implementing one of these interfaces; the
simulator never needs to change.

Conventions shared by all components
------------------------------------
- SI units inside: m, s, kg, N, V.
- ``drive`` is a :class:`DriveContext`: what the recording's drive is (direction,
  amplitude, frequency). Components that depend on the drive (``z_ba`` per
  direction, a ``z_ba`` surface) read it; the others ignore it.
- State vectors are flat 1-D float arrays. A component with internal states says how
  many (``n_states``, static) and provides their initial value and rate.
"""

import abc
import dataclasses
from collections.abc import Mapping

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Float

from .law_parameter import LawParameter


class DriveContext(eqx.Module):
    """What drives one recording, as seen by drive-dependent parameters.

    Attributes
    ----------
    backward:
        1.0 for a backward sawtooth, 0.0 otherwise (forward, sine, step) [-].
        A float rather than a bool so that it batches under ``vmap``.
    amplitude:
        Drive amplitude A [V] (0 when unknown).
    frequency:
        Drive frequency f [Hz] (0 when unknown or not periodic).
    """

    backward: Float[Array, ""]
    amplitude: Float[Array, ""]
    frequency: Float[Array, ""]

    @staticmethod
    def make(backward: bool | float = False, amplitude: float = 0.0, frequency: float = 0.0):
        """Build a context from Python values (or traced scalars)."""
        return DriveContext(
            jnp.asarray(backward, dtype=float),
            jnp.asarray(amplitude, dtype=float),
            jnp.asarray(frequency, dtype=float),
        )


class ContactKinematics(eqx.Module):
    """Relative motion at the contact, handed to friction laws.

    Attributes
    ----------
    xdot:
        Relative velocity v1 - v2 of piezo tip over slider [m/s].
    """

    xdot: Float[Array, ""]


class AbstractHysteresis(eqx.Module):
    """Rate-independent map from voltage to free stroke, Γ[U] [m].

    The memory (e.g. play-operator states [V]) is carried by the simulator and
    committed once per sub-step: ``output`` is evaluated with the memory of the
    sub-step's start (see docs/model.md "State and input").
    """

    @property
    @abc.abstractmethod
    def n_memory(self) -> int:
        """Number of memory states."""

    @abc.abstractmethod
    def initial_memory(self, u0: Float[Array, ""]) -> Float[Array, " n"]:
        """Memory at rest under voltage ``u0`` [V], as if it had risen from 0."""

    @abc.abstractmethod
    def output(self, memory: Float[Array, " n"], u: Float[Array, ""]) -> Float[Array, ""]:
        """Free stroke Γ [m] for voltage ``u`` [V], given the memory of the sub-step start."""

    @abc.abstractmethod
    def update(self, memory: Float[Array, " n"], u: Float[Array, ""]) -> Float[Array, " n"]:
        """Memory after the voltage has reached ``u`` [V]."""


class AbstractFriction(eqx.Module):
    """A friction law with one internal (bristle / elastic-strain) state ``z`` [m].

    The friction force acts on the piezo element with a minus sign and on the slider
    with a plus sign (docs/model.md: ``Mp·ẍ1 = ... − Ff``, ``Ms·ẍ2 = Ff + ...``).

    A law is one final class: its physics (the abstract methods below), its
    parameters as a parameter file holds them (:attr:`parameters`, with units,
    defaults, bounds and how they are fitted) and :meth:`from_params`; registered
    with :func:`~stickslip_jax.model.registry.register_friction_law`, parameter
    files, the identification and the CLI find it by name.
    """

    # Not stringified (no ``from __future__ import annotations`` in this module):
    # equinox recognises an abstract class variable only from the real annotation.
    parameters: eqx.AbstractClassVar[tuple[LawParameter, ...]]
    """The law's parameters in parameter-file order (:class:`LawParameter`)."""

    @classmethod
    @abc.abstractmethod
    def from_params(cls, values: Mapping[str, float]) -> "AbstractFriction":
        """The law from a parameter file's values [SI], by file name: every parameter of
        :attr:`parameters` the file gives or that has a default, each already within
        its bounds, aliases resolved (:func:`~stickslip_jax.model.registry.law_values`).
        Raises :class:`~stickslip_jax.model.registry.ParameterError` for combinations
        that bounds of single parameters cannot express (LuGre's ``F_s ≥ F_c``)."""

    def to_params(self) -> dict[str, float]:
        """This law's entries of a parameter file [SI], in :attr:`parameters` order:
        each parameter whose field this class has. Shorthands (``alias_for``: ``z_ba``)
        are left out: a file holds only what is read, so that editing any value of it
        changes the model. The inverse of :meth:`from_params`."""
        fields = {f.name for f in dataclasses.fields(self)}
        return {p.name: float(getattr(self, p.attr)) for p in self.parameters
                if not p.alias_for and p.attr in fields}

    @abc.abstractmethod
    def z_rate(self, z, xdot, drive: DriveContext):
        """dz/dt [m/s] for elastic state ``z`` [m] and relative velocity ``xdot`` [m/s]."""

    @abc.abstractmethod
    def force(self, z, zdot, xdot, drive: DriveContext):
        """Friction force Ff [N] from ``z`` [m], its rate [m/s] and ``xdot`` [m/s]."""

    @abc.abstractmethod
    def project(self, z, xdot, drive: DriveContext):
        """Map ``z`` back into its admissible set after a sub-step (saturation) [m]."""

    @abc.abstractmethod
    def z_at_rest(self, force, drive: DriveContext):
        """Elastic state [m] that carries a static friction force ``force`` [N]."""

    @abc.abstractmethod
    def stiffness(self, drive: DriveContext):
        """Small-motion contact stiffness dFf/dz [N/m] (for linearisation)."""

    @abc.abstractmethod
    def coulomb_force(self, drive: DriveContext):
        """Kinetic (Coulomb) friction level [N]: the most a steadily sliding contact
        carries, the ceiling of the force a blocked runner generates."""

    @abc.abstractmethod
    def strain_switches(self, drive: DriveContext) -> tuple:
        """Strain magnitudes |z| [m] at which ``ż`` changes form while ``z`` and ``ẋ``
        share a sign (the elasto-plastic break-away ``z_ba``, where α leaves 0); empty
        for a law that is smooth in ``z``. The simulator locates crossings of these
        inside a sub-step (:mod:`stickslip_jax.stepping`)."""

    @abc.abstractmethod
    def velocity_kink(self, z, drive: DriveContext):
        """How sharply ``ż`` bends where the relative velocity ``ẋ`` changes sign [-].

        The magnitude of the jump of ``∂ż/∂ẋ`` across ``ẋ = 0`` at strain ``z`` [m]: 0
        where the rate is smooth in ``ẋ`` there (pure elastic stick), positive where a
        sign reversal ends or starts a slip. The simulator locates a reversal inside a
        sub-step only where this is positive (:mod:`stickslip_jax.simulate`).
        """


class AbstractInputStage(eqx.Module):
    """Map from the recorded command voltage to the voltage reaching the piezo.

    The default (:class:`IdentityInput`) passes the command through. Amplifier
    dynamics (low-pass, slew limit) are stages with internal states.
    """

    @property
    @abc.abstractmethod
    def n_states(self) -> int:
        """Number of internal states."""

    @property
    def is_identity(self) -> bool:
        """True only for the pass-through stage (lets the simulator take a fast path)."""
        return False

    @abc.abstractmethod
    def initial_state(self, u0):
        """States at rest under command ``u0`` [V]."""

    @abc.abstractmethod
    def rate(self, state, u_command):
        """Time derivative of the states given the command voltage [V]."""

    @abc.abstractmethod
    def voltage(self, state, u_command):
        """Voltage reaching the piezo [V]."""

    @property
    def advances_in_closed_form(self) -> bool:
        """Whether :meth:`advance` gives the states (else RK4 steps of :meth:`rate`)."""
        return type(self).advance is not AbstractInputStage.advance

    def advance(self, state, u_start, u_end, h):
        """The states after ``h`` [s] under a command linear from ``u_start`` to
        ``u_end`` [V], in closed form, for stages that have one (stable at any step: a
        fit may drive a time constant towards 0, the pass-through). ``None`` (the
        default): the simulator takes Runge-Kutta steps of :meth:`rate`
        (:mod:`stickslip_jax.drive_path`)."""
        return None


class CoreState(eqx.Module):
    """The mechanical state handed to extensions (read-only views, SI units).

    Attributes: x1, v1 (piezo deformation [m] and rate [m/s]), x2, v2 (slider
    position [m], velocity [m/s]), z (elastic strain [m]), friction force ff [N],
    u (voltage at the piezo [V]), stroke (free stroke Γ [m]), push (the force the
    stack puts on its base beyond the preload [N], :meth:`~stickslip_jax.model.piezo.
    PiezoElement.push`, at the stroke before extensions add to it).
    """

    x1: Float[Array, ""]
    v1: Float[Array, ""]
    x2: Float[Array, ""]
    v2: Float[Array, ""]
    z: Float[Array, ""]
    ff: Float[Array, ""]
    u: Float[Array, ""]
    stroke: Float[Array, ""]
    push: Float[Array, ""] = 0.0


class ExtensionTerms(eqx.Module):
    """Additive contributions of one extension to the core equations.

    All default to zero. ``stroke`` [m] adds to the free stroke Γ (creep);
    ``force_piezo`` and ``force_slider`` [N] add to the right-hand sides of the
    piezo and slider equations; ``friction`` [N] adds to the friction force (acts on
    both bodies with opposite signs); ``output`` [m] adds to the measured q.
    """

    stroke: Float[Array, ""] = 0.0
    force_piezo: Float[Array, ""] = 0.0
    force_slider: Float[Array, ""] = 0.0
    friction: Float[Array, ""] = 0.0
    output: Float[Array, ""] = 0.0


class AbstractExtension(eqx.Module):
    """Extra physics: optional internal states plus additive terms.

    Creep, a structural mode, extra forces and learned corrections are extensions.
    ``terms`` is evaluated from the extension's own states and the mechanical
    state; terms that change the stroke must not depend on the stroke itself.
    """

    @property
    @abc.abstractmethod
    def n_states(self) -> int:
        """Number of internal states (may be 0)."""

    @abc.abstractmethod
    def initial_state(self, u0):
        """States at rest under voltage ``u0`` [V]."""

    @abc.abstractmethod
    def rate(self, state, core: CoreState, drive: DriveContext):
        """Time derivative of the extension's states."""

    @abc.abstractmethod
    def terms(self, state, core: CoreState, drive: DriveContext) -> ExtensionTerms:
        """Additive contributions to the core equations."""

    def project(self, state, xdot, drive: DriveContext):
        """Map the states back into their admissible set after a sub-step (default:
        unchanged; extra friction contacts saturate their strains here). ``xdot`` is
        the relative velocity v1 − v2 [m/s]."""
        return state

    def velocity_kink(self, state, drive: DriveContext):
        """Jump of the states' rates' slope across ``ẋ = 0`` [-] (default 0: smooth;
        extra friction contacts report theirs, see
        :meth:`AbstractFriction.velocity_kink`)."""
        return 0.0


class AbstractOutputMap(eqx.Module):
    """What the sensor makes of the model output q = x1 + x2 (+ extension output).

    Applied to whole traces after the simulation (delay, drift, gain).
    """

    @abc.abstractmethod
    def __call__(self, t: Float[Array, " T"], q: Float[Array, " T"]) -> Float[Array, " T"]:
        """Measured output [m] at times ``t`` [s] for model output ``q`` [m]."""

    def read(self, t: Float[Array, " T"], q: Float[Array, " T"],
             recording=None) -> Float[Array, " T"]:
        """The measured output of the dataset's recording ``recording`` (its index, an
        integer that may be traced; None for a trace of no dataset): a sensor with a
        quantity of its own per recording (:meth:`recordings`) reads each with it. By
        default every recording alike: ``self(t, q)``."""
        return self(t, q)

    def recordings(self) -> int:
        """How many recordings its per-recording quantities are for (0: none; then it
        reads any dataset)."""
        return 0
