"""SIGKILL, then the same command again, ends where an uninterrupted run ends (issue 47 item 7).

Each run is a process of its own that kills itself with SIGKILL (no cleanup, no ``finally``) at a chosen write:
``generator train --repair open`` in the middle of a VAE checkpoint (its state written, its ``vae.msgpack`` not),
``atlas`` in the middle of a generation (after some of its evaluations are committed). The rerun's files and store
must equal an uninterrupted run's, byte for byte (JSON that names its own directory aside).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from worldagent.store import RunStore

TESTS = Path(__file__).resolve().parent

# ``python CHILD OUT KILL_AT``: SIGKILL ourselves at the KILL_AT-th call of ``TARGET`` (0: never), then run ``MAIN``.
CHILD = """
import os, signal, sys
sys.path.insert(0, {tests!r})
{setup}
out, kill_at, calls = sys.argv[1], int(sys.argv[2]), [0]
owner, name = {target}
original = getattr(owner, name)
def dying(*args, **kwargs):
    calls[0] += 1
    if calls[0] == kill_at:
        os.kill(os.getpid(), signal.SIGKILL)
    return original(*args, **kwargs)
setattr(owner, name, dying)
{main}
"""


def child(tmp_path: Path, setup: str, target: str, main: str) -> Path:
    script = tmp_path / "child.py"
    script.write_text(CHILD.format(tests=str(TESTS), setup=textwrap.dedent(setup), target=target, main=textwrap.dedent(main)))
    return script


def run(script: Path, out: Path, kill_at: int = 0) -> int:
    return subprocess.run([sys.executable, str(script), str(out), str(kill_at)], capture_output=True, text=True, timeout=600).returncode


def files(folder: Path) -> dict[str, bytes]:
    """Every file's bytes, the folder's own path written as OUT (a generator records its dataset's path)."""
    return {p.name: p.read_bytes().replace(str(folder).encode(), b"OUT") for p in sorted(folder.iterdir()) if p.is_file()}


@pytest.mark.slow  # three processes, each importing JAX and training (about 12 CPU-s each)
def test_generator_train_repair_open_killed_mid_checkpoint_resumes_to_the_same_files(tmp_path):
    script = child(
        tmp_path,
        setup="""
        import worldagent.worlds.vae as vae_module
        from worldagent.commands.generator import train_generator
        from worldagent.worlds.vae import VAEConfig
        from pathlib import Path
        """,
        target="vae_module, 'write_bytes'",  # two per epoch: the training state, then vae.msgpack
        main="""
        config = VAEConfig(encoder=(32,), decoder=(32,), latent_dim=4, epochs=6, batch_size=16, warmup_epochs=1)
        train_generator("harvest", Path(out), None, 64, 0, config, {}, progress=False, repair_name="open")
        """,
    )
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    assert run(script, whole) == 0
    assert run(script, killed, kill_at=6) == -signal.SIGKILL  # epoch 3's state written, its vae.msgpack and vae.json not
    assert len(json.loads((killed / "vae.json").read_text())["history"]) == 2
    assert run(script, killed) == 0
    assert files(killed) == files(whole) and {"training.msgpack", "vae.msgpack", "generator.json"} <= set(files(whole))


def stored(folder: Path) -> list[tuple]:
    with RunStore(folder, create=False) as store:
        return [(e.campaign, e.generation, e.slot, e.latent.tolist(), e.score, e.episodes) for e in store.evaluations(with_worlds=False)]


@pytest.mark.slow  # four processes on the toy env, each importing JAX
def test_atlas_killed_mid_generation_resumes_to_the_same_store_and_files(tmp_path):
    setup = """
    from pathlib import Path
    import toy_env
    from worldagent.store import RunStore
    from worldagent.cli import app
    from worldagent.commands.generator import train_generator
    from worldagent.worlds.vae import VAEConfig
    toy = toy_env.registered()
    toy.__enter__()
    """
    generator = tmp_path / "generator"
    make = child(tmp_path, setup, "RunStore, 'add'", """
        config = VAEConfig(encoder=(32,), decoder=(32,), latent_dim=4, epochs=4, batch_size=16, warmup_epochs=1)
        train_generator(toy_env.NAME, Path(out), None, 128, 0, config, {}, progress=False)
        """)  # fmt: skip
    assert run(make, generator) == 0
    atlas = child(tmp_path, setup, "RunStore, 'add'", f"""
        app(["atlas", toy_env.NAME, "--agent", "scripted/homing", "--generator", {str(generator)!r}, "--budget", "42", "--repeats", "2",
             "--cells", "4", "--confirm", "0", "--no-explain", "--quiet", "--out", out], standalone_mode=False)
        """)  # fmt: skip
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    assert run(atlas, whole) == 0
    assert run(atlas, killed, kill_at=30) == -signal.SIGKILL  # generation 1 half committed
    assert len(stored(killed)) == 29
    assert run(atlas, killed) == 0
    assert stored(killed) == stored(whole) and len(stored(whole)) == 42
    assert files(killed).keys() == files(whole).keys()
    name = next(n for n in files(whole) if n.endswith(".json"))
    assert files(killed)[name] == files(whole)[name]
