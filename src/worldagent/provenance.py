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
