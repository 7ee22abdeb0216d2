"""Default (empty) slots of the composition: identity input stage and output map."""

from __future__ import annotations

import jax.numpy as jnp

from .base import AbstractInputStage, AbstractOutputMap


class IdentityInput(AbstractInputStage):
    """The piezo receives the recorded command voltage unchanged."""

    @property
    def n_states(self) -> int:
        return 0

    @property
    def is_identity(self) -> bool:
        return True

    def initial_state(self, u0):
        return jnp.zeros((0,))

    def rate(self, state, u_command):
        return jnp.zeros((0,))

    def voltage(self, state, u_command):
        return u_command


class IdentityOutput(AbstractOutputMap):
    """The sensor reads q = x1 + x2 exactly (docs/model.md "Output")."""

    def __call__(self, t, q):
        return q
