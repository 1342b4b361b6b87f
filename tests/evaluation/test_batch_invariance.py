"""A world's metrics depend on its latent, its seed and the agent: never on its batch or devices.

The suite compiles at XLA's lowest optimisation level (tests/conftest.py), where nothing is
fused into FMAs and every shape happens to give the same bits. Users run optimised programs,
where a batch of 21 worlds and one of 10 did not. So the check runs in fresh processes with the
default compiler settings, once on one CPU device and once on two.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from worldagent.worlds.dataset import make_dataset
from worldagent.worlds.generator import build_generator, save_generator
from worldagent.worlds.vae import VAEConfig, train_vae

pytestmark = pytest.mark.integration  # whole-pipeline work: .ci/run's integration step runs it

SCRIPT = r"""
import json, sys
import jax, jax.numpy as jnp, numpy as np

out = {}
if sys.argv[2] == "generator":  # a generator made in the test's process (its weights need no optimised compiler)
    from worldagent.search.objectives import generate
    from worldagent.worlds.generator import load_generator

    generator = load_generator(sys.argv[3])[0]
    z = jax.random.normal(jax.random.key(1), (42, generator.latent_dim))
    for size in (42, 7, 1):
        parts = [np.asarray(generate(generator, z[s : s + size], logits=True)) for s in range(0, 42, size)]
        out[f"generator/{size}"] = np.concatenate(parts).tolist()
    json.dump(out, open(sys.argv[1], "w"))
    sys.exit()
from worldagent.agents.external import HostPolicy
from worldagent.agents.policy import Policy
from worldagent.envs.racing.env import ParticleRacing
from worldagent.envs.racing.tracks import generate_tracks
from worldagent.evaluation.local import evaluate

env = ParticleRacing()
params = env.default_params.replace(respawn=True)  # every episode runs its 300 steps
rng = np.random.default_rng(0)
w1 = rng.normal(size=(env.observation_shape[0], 32)).astype(np.float32)
w2 = rng.normal(size=(32, env.num_actions)).astype(np.float32)
policies = {  # one that ignores what it sees, and one that any bit of what it sees can tip
    "jitted": Policy(None, lambda p, obs, key, state=None: jax.random.randint(key, (), 0, env.num_actions), "random"),
    "host": HostPolicy(lambda obs: np.tanh(obs @ w1) @ w2, env.num_actions),
}
if sys.argv[2] == "sharded":  # only jitted episodes are sharded over devices
    policies.pop("host")
worlds = generate_tracks(np.arange(42))
keys = jax.random.split(jax.random.key(3), (42, 8))
for name, policy in policies.items():
    for size in (42,) if sys.argv[2] == "sharded" else (42, 7, 1):  # two devices: compared with one device's 42
        # 7 worlds one by one and 14 in sevens suffice (each call pads to a full batch of episodes)
        count = {42: 42, 7: 14, 1: 7}[size]
        parts = [
            evaluate(env, policy, jax.tree_util.tree_map(lambda leaf: leaf[s : s + size], worlds), 8, None, params, keys=keys[s : s + size])["return"]
            for s in range(0, count, size)
        ]
        out[f"{name}/{size}"] = np.concatenate(parts).tolist()
json.dump(out, open(sys.argv[1], "w"))
"""


def start_script(tmp_path: Path, devices: int, mode: str, *args: str) -> tuple[subprocess.Popen, Path]:
    """The script started in ``mode`` in a fresh process with default XLA settings and ``devices``
    CPU devices, and the file it writes."""
    out = tmp_path / f"{mode}.json"
    env = {key: value for key, value in os.environ.items() if key not in ("XLA_FLAGS", "WORLDAGENT_EPISODES_PER_CALL")}
    # 64 episodes a call (the default is 256) keeps 42 batches of one world cheap; any fixed size must do
    env.update(JAX_PLATFORMS="cpu", XLA_FLAGS=f"--xla_force_host_platform_device_count={devices}", WORLDAGENT_EPISODES_PER_CALL="64")
    return subprocess.Popen([sys.executable, "-c", SCRIPT, str(out), mode, *args], env=env), out


def finish(started: list[tuple[subprocess.Popen, Path]]) -> dict:
    """The results of the started scripts, merged (any still running are killed if one fails or hangs)."""
    try:
        for process, _ in started:
            assert process.wait(timeout=400) == 0, f"the script failed (exit status {process.returncode})"
    finally:
        for process, _ in started:
            if process.poll() is None:
                process.kill()
    return {key: value for _, out in started for key, value in json.loads(out.read_text()).items()}


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """(one device's results, two devices' results); with two, only the jitted episodes: nothing
    else is sharded. The processes run side by side."""
    tmp_path = tmp_path_factory.mktemp("invariance")
    episodes = [start_script(tmp_path, 1, "episodes"), start_script(tmp_path, 2, "sharded")]
    try:
        data = make_dataset("harvest", 64, seed=0, progress=False)
        config = VAEConfig(encoder=(32,), decoder=(32,), epochs=1, batch_size=16)
        vae = train_vae(data, config, progress=False)
        saved = save_generator(tmp_path / "generator", vae, data.save(tmp_path / "harvest.npz"), build_generator(vae, data))
    except BaseException:
        for process, _ in episodes:  # not left running
            process.kill()
        raise
    one_device = finish([*episodes[:1], start_script(tmp_path, 1, "generator", str(saved))])
    return one_device, finish(episodes[1:])


@pytest.mark.parametrize("what", ["jitted", "host", "generator"])
def test_batches_of_1_7_and_42_give_identical_results(results, what):
    one_device, _ = results
    whole = one_device[f"{what}/42"]
    assert len({json.dumps(whole[0]), json.dumps(whole[1])}) == 2  # the worlds differ: the comparison means something
    for size in (7, 1):
        got = one_device[f"{what}/{size}"]
        assert got == whole[: len(got)], f"{what}: batches of {size} changed a result"


def test_two_devices_give_the_results_of_one(results):
    one_device, two_devices = results
    assert two_devices and all(two_devices[name] == one_device[name] for name in two_devices)
