"""Multi-contact runners (Nguyen 2012 §2): several friction contacts in parallel.

Nguyen's runner is held and driven by six ruby hemispheres, each pressed on it with
its own normal force; the lumped model of the paper has one "virtual" contact
carrying the sum. Here the runner keeps the actuator's own contact (contact 0, the
``friction`` slot) and :class:`ExtraContacts` adds contacts 1..K−1 as an extension:
one friction state per contact, each with its own law and parameters, all seeing the
same relative velocity (the drive's piezo elements move together; their individual
dynamics are neglected, as in Nguyen eq. 5-7), their forces summed on both bodies.
The contact laws are one batched Module (leading axis = contact) evaluated with
``jax.vmap``.

:func:`multi_contact` splits a lumped contact into K contacts by normal-force shares.
With elasto-plastic contacts whose stiffness is proportional to the normal force and
whose break-away strain is not, every contact follows the same z(t) and the runner
moves exactly as the lumped one (the paper's special case). With preload-dependent
(CEIM) contacts the break-away strain grows with each contact's normal force, so an
uneven spread of the preload changes step length and 0-amplitude threshold.

The extra contacts start unstrained; a constant external force at rest is carried by
contact 0 alone.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .base import AbstractExtension, AbstractFriction, CoreState, DriveContext, ExtensionTerms
from .registry import held_parameters


class ExtraContacts(AbstractExtension):
    """Contacts 1..K−1 of a multi-contact runner (see the module docstring).

    Attributes
    ----------
    contacts: one friction law whose array leaves have a leading axis of length K−1
        (build it with :func:`stack_contacts`); each contact's strain z_k [m] is a state.
    """

    contacts: AbstractFriction

    @property
    def n_states(self) -> int:
        return int(jax.tree_util.tree_leaves(self.contacts)[0].shape[0])

    def initial_state(self, u0):
        return jnp.zeros(self.n_states) + 0.0 * jnp.asarray(u0, dtype=float)

    def _each(self, fn, *args):
        return jax.vmap(fn)(self.contacts, *args)

    def rate(self, state, core: CoreState, drive: DriveContext):
        xdot = core.v1 - core.v2
        return self._each(lambda c, z: c.z_rate(z, xdot, drive), state)

    def terms(self, state, core: CoreState, drive: DriveContext) -> ExtensionTerms:
        xdot = core.v1 - core.v2
        zdot = self.rate(state, core, drive)
        forces = self._each(lambda c, z, zd: c.force(z, zd, xdot, drive), state, zdot)
        return ExtensionTerms(friction=jnp.sum(forces))

    def project(self, state, xdot, drive: DriveContext):
        return self._each(lambda c, z: c.project(z, xdot, drive), state)

    def velocity_kink(self, state, drive: DriveContext):
        return jnp.sum(self._each(lambda c, z: c.velocity_kink(z, drive), state))

    def forces(self, states, core: CoreState, drive: DriveContext):
        """Friction force of each extra contact [N] (for inspection)."""
        xdot = core.v1 - core.v2
        zdot = self.rate(states, core, drive)
        return self._each(lambda c, z, zd: c.force(z, zd, xdot, drive), states, zdot)


def stack_contacts(laws) -> AbstractFriction:
    """One batched friction Module from a list of laws of one class (leading axis)."""
    laws = list(laws)
    if not laws:
        raise ValueError("no contacts to stack")
    if len({type(law) for law in laws}) != 1:
        raise ValueError("all contacts of a runner must use the same friction law class")
    return jax.tree.map(lambda *xs: jnp.stack(xs), *laws)


def split_contact(friction: AbstractFriction, share: float) -> AbstractFriction:
    """The contact that carries ``share`` of the lumped contact's normal force: the
    law's parameters flagged ``with_normal_force``
    (:class:`~stickslip_jax.model.registry.LawParameter`) times ``share``, the others
    unchanged.

    Elasto-plastic: stiffnesses and dampings (ρ0, ρ1, ρ2) scale with the share, the
    break-away strains do not (so the Coulomb level scales with it too). CEIM: the
    same material under ``share``·preload, with its σ1 scaled. A law that flags none
    cannot be split (``TypeError``).
    """
    share = float(share)
    attrs = tuple(p.attr for p in held_parameters(friction) if p.with_normal_force)
    if not attrs:
        raise TypeError(f"cannot split a {type(friction).__name__} contact: its law flags "
                        f"no parameter as proportional to the normal force "
                        f"(LawParameter.with_normal_force)")
    return eqx.tree_at(lambda c: tuple(getattr(c, a) for a in attrs), friction,
                       tuple(getattr(friction, a) * share for a in attrs))


def multi_contact(actuator, shares):
    """The actuator with its lumped contact split into ``len(shares)`` contacts.

    ``shares``: each contact's part of the total normal force (positive; normalised
    to sum 1). Contact 0 stays in the ``friction`` slot; the others become one
    :class:`ExtraContacts` extension. Returns a new actuator.
    """
    shares = np.asarray(shares, dtype=float)
    if shares.ndim != 1 or shares.size < 1 or np.any(shares <= 0):
        raise ValueError(f"shares must be positive numbers, got {shares!r}")
    shares = shares / shares.sum()
    lumped = actuator.friction
    first = split_contact(lumped, shares[0])
    act = eqx.tree_at(lambda a: a.friction, actuator, first)
    if shares.size == 1:
        return act
    extra = ExtraContacts(stack_contacts([split_contact(lumped, s) for s in shares[1:]]))
    return act.with_extension(extra)
