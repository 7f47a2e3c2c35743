"""A numerical floor that holds in float32 as in float64, and a branch predicate that stays a branch under vmap."""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["tiny", "any_in_batch"]


def tiny(*arrays) -> float:
    """max(1e-300, the smallest normal number of the arrays' float dtype): the floor under a value that goes
    into a log, a sqrt or a division. 1e-300 alone rounds to 0 in float32 (log 0 = -inf, 0/0 gradients:
    a float32 joint fit's error bars came out NaN); in float64 it stays 1e-300."""
    return max(1e-300, float(jnp.finfo(jnp.result_type(*arrays)).tiny))


@jax.custom_batching.custom_vmap
def any_in_batch(x):
    """``jnp.any(x)``, and under ``jax.vmap`` the any over the whole batch, unbatched.

    The predicate of a ``lax.cond`` whose branch is needed by few records: a batched predicate turns the
    cond into a select that computes the branch for every record of a chunk at every call, while an
    unbatched one runs the branch only where some record of the chunk needs it. The branch must leave the
    records that do not need it unchanged (it applies per element, as ``jnp.where`` does)."""
    return jnp.any(x)


@any_in_batch.def_vmap
def _any_in_batch_vmap(axis_size, in_batched, x):
    return jnp.any(x), False
