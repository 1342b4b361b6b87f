"""What a run directory records about where it was made: package versions and the device.

One place for both (training runs, the reproduce manifest and influence runs all record them),
so every run directory describes its provenance the same way (DESIGN.md "Conventions").
"""

from __future__ import annotations

import platform


def versions() -> dict[str, str]:
    """Versions of the packages whose behaviour the results depend on, and of Python."""
    import flax
    import jax
    import numpy
    import optax

    import worldagent

    return {
        "worldagent": getattr(worldagent, "__version__", "?"),
        "jax": jax.__version__,
        "flax": flax.__version__,
        "optax": optax.__version__,
        "numpy": numpy.__version__,
        "python": platform.python_version(),
    }


def device() -> str:
    """The JAX devices of this process, e.g. ``"TFRT_CPU_0 (cpu)"``."""
    import jax

    return ", ".join(f"{d} ({d.device_kind})" for d in jax.devices())


def fingerprint(tree, name: str = "") -> str:
    """Short SHA-256 of a pytree's leaves (shapes, dtypes, bytes) and a name: which agent / G made a cache."""
    import hashlib

    import jax
    import numpy as np

    digest = hashlib.sha256(name.encode())
    for leaf in jax.tree_util.tree_leaves(tree):
        if hasattr(leaf, "dtype") and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            leaf = jax.random.key_data(leaf)
        array = np.asarray(leaf)
        digest.update(f"{array.shape}{array.dtype}".encode())
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()[:16]
