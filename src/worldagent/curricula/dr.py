"""``dr``: domain randomisation, every world drawn afresh from the training distribution (the default).

z ~ N(0, I) for a generator, or a pool's worlds by weight: what training did before curricula,
and the baseline every curriculum is compared against. Nothing is scored.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

HELP = "domain randomisation: every world drawn afresh (z ~ N(0, I), or a pool by weight); the default"
DEFAULTS: dict = {}


@struct.dataclass
class DomainRandomisation:
    """A fixed world distribution seen through the curriculum interface (it ignores scores).

    Attributes:
        worlds: the distribution (``distributions.WorldPool`` or ``LatentWorlds``).
    """

    worlds: Any
    name: str = struct.field(pytree_node=False, default="dr")

    adaptive = False

    def init(self, key: jax.Array) -> tuple:
        del key
        return ()

    def sample(self, state: tuple, key: jax.Array, n: int):
        """The next worlds of ``n`` envs: one draw per key, exactly as training drew them before curricula."""
        from worldagent.curricula.replay import Draw

        worlds = jax.vmap(self.worlds.sample)(jax.random.split(key, n))
        return Draw(jnp.zeros((n, 0), jnp.float32), jnp.full(n, -1, jnp.int32), worlds)

    def update(self, state: tuple, z, slot, score, valid) -> tuple:
        return state

    def slot_of(self, state: tuple, z, slot):
        return slot

    def learns_from(self, replayed: jax.Array) -> jax.Array:
        return jnp.ones(replayed.shape, jnp.float32)


def build(worlds: Any, settings: dict, target=None):
    """``dr`` over ``worlds``; it takes no settings and no target."""
    from worldagent.errors import WorldagentError

    if settings:
        raise WorldagentError(f"curriculum dr takes no settings (got {', '.join(settings)}); drop --curriculum-set or pick plr, accel or target.")
    if target is not None:
        raise WorldagentError("curriculum dr ignores --target; pick --curriculum target (or plr/accel) to train toward it.")
    return DomainRandomisation(worlds)
