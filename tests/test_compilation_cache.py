"""The command-line tool keeps compiled programs on disk (``worldagent.compilation``)."""

from __future__ import annotations

from pathlib import Path

from worldagent.compilation import VARIABLE, cache_dir


def test_the_cache_lives_in_the_users_cache_folder_unless_told_otherwise(monkeypatch, tmp_path):
    monkeypatch.delenv(VARIABLE, raising=False)
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert cache_dir() == tmp_path / "worldagent" / "xla"
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "jax"))
    assert cache_dir() is None  # JAX's own setting decides
    monkeypatch.setenv(VARIABLE, str(tmp_path / "mine"))
    assert cache_dir() == tmp_path / "mine"
    for off in ("", "0"):
        monkeypatch.setenv(VARIABLE, off)
        assert cache_dir() is None


def test_a_command_fills_the_cache_and_the_next_one_reads_it(tmp_path):
    """Two fresh processes run the same evaluation; the first writes compiled programs, the second finds them (JAX counts its hits)."""
    import subprocess
    import sys

    script = (
        "import jax, numpy as np\n"
        "from jax._src import monitoring\n"
        "hits = []\n"
        "monitoring.register_event_listener(lambda name, **kw: hits.append(name) if name == '/jax/compilation_cache/cache_hits' else None)\n"
        "from worldagent.compilation import use_compilation_cache\n"
        "use_compilation_cache()\n"
        "jax.config.update('jax_persistent_cache_min_compile_time_secs', 0)\n"
        "print(jax.jit(lambda x: (x @ x.T).sum())(np.ones((64, 64), np.float32)), len(hits))\n"
    )
    env = {**__import__("os").environ, VARIABLE: str(tmp_path / "xla")}
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    runs = [subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True).stdout.split() for _ in range(2)]
    assert [hits for _, hits in runs] == ["0", "1"] and runs[0][0] == runs[1][0] == "262144.0"
    assert any(Path(tmp_path / "xla").iterdir())
