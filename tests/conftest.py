"""Shared session fixtures: small datasets and small trained VAEs / generators, built once."""

from __future__ import annotations

import atexit
import contextlib
import fcntl
import os
import shutil
import sys
import tempfile
from pathlib import Path

# Test programs are tiny and compiled once each, and compiling is most of the suite's time: compile
# them fast, not well. Besides LLVM's optimisation, XLA's CPU fusion emitters, XNNPACK's fusions and
# split code generation cost compile time that these short runs never win back: without them the
# default run took 487 CPU-s instead of 649 (2026-11-29, same commit, all passing). Set before JAX
# starts its backend; a user's XLA_FLAGS win.
TEST_XLA_FLAGS = (
    "--xla_backend_optimization_level=0 --xla_llvm_disable_expensive_passes=true"
    " --xla_cpu_use_fusion_emitters=false --xla_cpu_use_xnnpack=false --xla_cpu_parallel_codegen_split_count=1"
)
os.environ.setdefault("XLA_FLAGS", TEST_XLA_FLAGS)
# Tests evaluate a handful of worlds at a time: pad each evaluation call to 16 episodes, not the
# 256 users get (any fixed size keeps results batch-invariant; test_batch_invariance checks 64).
os.environ.setdefault("WORLDAGENT_EPISODES_PER_CALL", "16")

# Many tests compile the same programs (an evaluator, a trainer) from fresh Python closures; a
# compilation cache for this session compiles each once. It starts empty every run, so CI timings
# stay honest. Set as environment variables before JAX starts: pytest-xdist workers and the processes
# `reproduce` spawns for its environments inherit them, and share the folder.
if "WORLDAGENT_TEST_JAX_CACHE" not in os.environ:
    os.environ["WORLDAGENT_TEST_JAX_CACHE"] = tempfile.mkdtemp(prefix="worldagent-jax-cache-")
    atexit.register(shutil.rmtree, os.environ["WORLDAGENT_TEST_JAX_CACHE"], ignore_errors=True)
CACHE_DIR = os.environ["WORLDAGENT_TEST_JAX_CACHE"]
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", CACHE_DIR)
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0")
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES", "0")

import jax  # noqa: E402
import pytest  # noqa: E402

from worldagent.worlds.dataset import WorldDataset, make_dataset  # noqa: E402
from worldagent.worlds.generator import build_generator  # noqa: E402
from worldagent.worlds.vae import TrainedVAE, VAEConfig, train_vae  # noqa: E402

jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])  # should JAX have started already
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)

# ``import toy_env`` (the toy environment of tests/toy_env) under any --import-mode.
if str(Path(__file__).parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).parent))


# Small but long enough for the latent to be used: on 512 harvest maps a VAE needs a few hundred
# updates before it beats the mean image (fewer, and the posterior has not left the prior yet).
SMALL_VAE = VAEConfig(encoder=(128, 64), decoder=(64, 128), epochs=30, batch_size=16, learning_rate=2e-3, warmup_epochs=2)


# Folders whose files share an expensive session fixture (a whole reproduce run) run on one worker.
SHARED_FIXTURE_FOLDERS = ("reproduce",)
WORKERS = 2  # CI has 2 cores


def xdist_loaded(config) -> bool:
    return config.pluginmanager.hasplugin("xdist")


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook turns -n into workers
def pytest_cmdline_main(config):
    """Plain ``pytest`` runs on WORKERS xdist workers grouped by file (``--dist loadgroup``); an
    explicit ``-n``/``--dist`` wins. Here rather than in addopts, which would make ``-p no:xdist``
    a usage error."""
    if not xdist_loaded(config) or hasattr(config, "workerinput") or config.getoption("usepdb", False):
        return
    if config.option.numprocesses is None:
        config.option.numprocesses = WORKERS
    if config.option.dist == "no":
        config.option.dist = "loadgroup"


# Workers parse the command line afresh, so a --dist set above never reaches them, and without it
# they do not tag tests with their group: the controller then scatters a file's tests. Tell them.
@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node):
    node.workerinput["worldagent_loadgroup"] = node.config.option.dist == "loadgroup"


# .ci/run sets this: its `pytest` (the README's command) runs the integration and example tests too, in the same
# session, so they share its compilation cache and session fixtures (as steps of their own they compiled it all again).
WITH_INTEGRATION = os.environ.get("WORLDAGENT_TEST_INTEGRATION") == "1"


def pytest_configure(config):
    if getattr(config, "workerinput", {}).get("worldagent_loadgroup"):
        config.option.loadgroup = True
    if WITH_INTEGRATION:  # pyproject's default selection, less its "not integration"; an explicit -m is left alone
        config.option.markexpr = config.option.markexpr.replace(" and not integration", "").replace(" and not example", "")


@pytest.hookimpl(tryfirst=True)  # before xdist reads the groups
def pytest_collection_modifyitems(config, items):
    """Put each test file, or each folder of SHARED_FIXTURE_FOLDERS, on one xdist worker."""
    if not xdist_loaded(config):
        return  # no workers to group (and no xdist_group marker registered)
    for item in items:
        path = item.path.relative_to(Path(__file__).parent)
        group = path.parts[0] if path.parts[0] in SHARED_FIXTURE_FOLDERS else str(path)
        item.add_marker(pytest.mark.xdist_group(group))


@pytest.fixture(scope="session")
def small_vae():
    """Settings of the small VAEs the tests train."""
    return SMALL_VAE


@contextlib.contextmanager
def built_once(name: str):
    """The path ``name`` in this run's cache, one xdist worker at a time: the first builds and saves there,
    the others wait and load (a session fixture otherwise costs every worker that uses it)."""
    with open(Path(CACHE_DIR) / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        yield Path(CACHE_DIR) / name


def shared_dataset(env: str, count: int) -> WorldDataset:
    with built_once(f"dataset-{env}-{count}.npz") as path:
        if not path.exists():
            make_dataset(env, count, 0, progress=False).save(path)
        return WorldDataset.load(path)  # every worker the same, as loaded


def shared_vae(data: WorldDataset) -> TrainedVAE:
    with built_once(f"vae-{data.env}-{data.fingerprint}") as folder:
        if not (folder / "vae.json").exists():
            train_vae(data, SMALL_VAE, progress=False).save(folder)
        return TrainedVAE.load(folder)  # every worker the same, as loaded


@pytest.fixture(scope="session")
def racing_data():
    return shared_dataset("racing", 256)


@pytest.fixture(scope="session")
def harvest_data():
    return shared_dataset("harvest", 512)


@pytest.fixture(scope="session")
def racing_vae(racing_data):
    return shared_vae(racing_data)


@pytest.fixture(scope="session")
def harvest_vae(harvest_data):
    return shared_vae(harvest_data)


@pytest.fixture(scope="session")
def racing_generator(racing_vae, racing_data):
    return build_generator(racing_vae, racing_data)


@pytest.fixture(scope="session")
def harvest_generator(harvest_vae, harvest_data):
    return build_generator(harvest_vae, harvest_data)
