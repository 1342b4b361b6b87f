"""XLA's persistent compilation cache for the command-line tool.

Most of a short command's time on a CPU is XLA compiling its programs (an evaluation of harvest's
agents: 6 s to compile, 1 s to play 64 episodes). With the cache on disk a program compiled once is
loaded in a fraction of that by every later command and by every process of ``reproduce``: a
rerun, a resumed run, and the same evaluation program compiled in two env chains. A cached program
is the program XLA would compile, so results are the same bit for bit.

``WORLDAGENT_COMPILATION_CACHE`` names its directory (``""`` or ``0``: no cache); without it JAX's own
``JAX_COMPILATION_CACHE_DIR`` is used as set, else ``$XDG_CACHE_HOME/worldagent/xla`` (``~/.cache/...``).
It is not capped: a quick run writes about 5 MB, and capping it needs the ``filelock`` package, which JAX
asks for on every read (a fresh install warned). Delete the folder to empty it.
"""

from __future__ import annotations

import os
from pathlib import Path

VARIABLE = "WORLDAGENT_COMPILATION_CACHE"


def cache_dir() -> Path | None:
    """Where compiled programs are kept, or None (off, or JAX's own ``JAX_COMPILATION_CACHE_DIR`` decides)."""
    given = os.environ.get(VARIABLE)
    if given is not None:
        return Path(given).expanduser() if given not in ("", "0") else None
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return None
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "worldagent" / "xla"


def use_compilation_cache() -> Path | None:
    """Turn the cache on for this process and the processes it starts (their environment names it); returns its
    directory, or None where it is off or cannot be made (a read-only home: commands compile as before)."""
    directory = cache_dir()
    if directory is None:
        return None
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    import jax

    os.environ["JAX_COMPILATION_CACHE_DIR"] = str(directory)  # spawned processes (reproduce's env chains) read it
    jax.config.update("jax_compilation_cache_dir", str(directory))
    return directory
