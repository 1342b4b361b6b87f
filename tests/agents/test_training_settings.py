"""Training settings: the algorithms' own defaults, each env's declared departures, ``--set`` on top."""

from __future__ import annotations

import csv
import dataclasses
import json
import subprocess
import sys
import warnings

import jax.numpy as jnp
import pytest
from flax import struct
from typer.testing import CliRunner

from toy_env import registered
from toy_env.env import ToyGrid, ToyParams
from worldagent.agents.acktr import ACKTRConfig
from worldagent.agents.algorithms import parse_settings, training_config
from worldagent.agents.dqn import DQNConfig
from worldagent.agents.ppo import PPOConfig
from worldagent.cli import app
from worldagent.commands.console import friendly_errors, one_line_warning
from worldagent.envs import registry
from worldagent.errors import WorldagentError

runner = CliRunner()


def one_line_error(result, *messages: str) -> bool:
    """Exit code 2 and a single ``error:`` line holding every message."""
    lines = result.output.strip().splitlines()
    return result.exit_code == 2 and len(lines) == 1 and lines[0].startswith("error:") and all(m in lines[0] for m in messages)


def test_defaults_are_the_algorithms_not_racings():
    for config in (PPOConfig(), ACKTRConfig()):
        assert (config.reward_scale, config.respawn, config.crash_warmup, config.quadratic) == (1.0, False, 0.0, False)
    acktr = ACKTRConfig()  # ikostrikov's pytorch-a2c-ppo-acktr, the paper's implementation
    assert (acktr.num_envs, acktr.num_steps, acktr.ent_coef, acktr.kl_clip, acktr.learning_rate) == (16, 5, 0.01, 0.001, 0.25)


def test_racing_declares_its_departures_in_its_spec_and_harvest_none():
    racing = registry.get("racing")
    ppo = training_config("racing", "ppo")
    assert (ppo.reward_scale, ppo.respawn, ppo.crash_warmup) == (0.01, True, 0.0)
    assert ppo == PPOConfig().replace(**racing.training_settings("ppo"))
    acktr = training_config("racing", "acktr")
    assert (acktr.reward_scale, acktr.respawn, acktr.num_envs, acktr.num_steps, acktr.ent_coef, acktr.kl_clip) == (0.01, True, 32, 16, 0.001, 0.01)
    rays = racing.training_settings("acktr", {"observation": "rays"})  # the observation's departures over the base ones
    assert rays["respawn"] and (rays["crash_warmup"], rays["kl_clip"], rays["learning_rate"]) == (0.5, 0.003, 1.0)
    assert training_config("harvest", "dqn") == DQNConfig() and registry.get("harvest").training_settings("dqn") == {}


def test_set_overrides_the_env_which_overrides_the_algorithm():
    assert PPOConfig().crash_warmup == 0.0
    assert training_config("racing", "ppo", options={"observation": "rays"}).crash_warmup == 0.5
    chosen = parse_settings(["crash_warmup=0.2", "reward_scale=1"], ["ppo"])["ppo"]
    config = training_config("racing", "ppo", options={"observation": "rays"}, **chosen)
    assert (config.crash_warmup, config.reward_scale, config.respawn, config.quadratic) == (0.2, 1.0, True, True)


def test_racing_training_params_come_from_its_spec():
    racing = registry.get("racing")
    params = racing.make_env()[1]
    assert not params.respawn  # evaluation keeps the paper's rule
    trained = racing.training_params(params, training_config("racing", "ppo"), jnp.float32(0.0))
    assert trained.respawn and trained.crash_penalty == params.crash_penalty
    warming = racing.training_params(params, PPOConfig(crash_warmup=0.5), jnp.float32(0.25))
    assert not warming.respawn and float(warming.crash_penalty) == pytest.approx(params.crash_penalty / 2)


@struct.dataclass
class FieldedParams(ToyParams):
    """Toy params with the names racing's used to be found by (``respawn``, ``crash_penalty``)."""

    respawn: bool = False
    crash_penalty: float = 1.0


@dataclasses.dataclass(frozen=True)
class ReportingGrid(ToyGrid):
    """The toy grid reporting the params it was stepped with, per episode (so the curve shows them)."""

    def step(self, key, state, action, params):
        obs, state, reward, terminated, truncated, info = super().step(key, state, action, params)
        return obs, state, reward, terminated, truncated, {**info, "respawn": params.respawn, "crash_penalty": params.crash_penalty}


def make_fielded(options):
    """The reporting grid and its params with racing-like names."""
    del options
    return ReportingGrid(), FieldedParams()


def train_fielded(tmp_path, training_params=None) -> tuple[dict, dict]:
    """``worldagent train`` on the toy with racing-like param names, asked for respawn and a warm-up:
    (the config run.json records, the curve's first row)."""
    with registered() as toy:
        spec = registry.register(dataclasses.replace(toy, name="fielded_toy", make=make_fielded, training_params=training_params))
        try:
            args = ["train", "fielded_toy", "--out", str(tmp_path), "--episodes", "4", "--quiet", "--set", "respawn=true"]
            result = runner.invoke(app, [*args, "--set", "crash_warmup=0.5", "--set", "num_envs=2", "--set", "hidden=8"])
        finally:
            registry.unregister(spec.name)
    assert result.exit_code == 0, result.output
    with open(tmp_path / "curve.csv", newline="") as handle:
        return json.loads((tmp_path / "run.json").read_text())["config"], next(csv.DictReader(handle))


@pytest.mark.integration
def test_set_applies_is_recorded_and_a_toy_with_racing_like_fields_is_not_rewritten(tmp_path):
    config, first = train_fielded(tmp_path)
    assert (config["respawn"], config["crash_warmup"], config["num_envs"], config["hidden"], config["total_episodes"]) == (True, 0.5, 2, [8], 4)
    assert config["num_steps"] == 32 and config["reward_scale"] == 1.0  # the toy's departures and PPO's default where --set is silent
    assert float(first["respawn"]) == 0.0 and float(first["crash_penalty"]) == 1.0  # respawn and the warm-up change nothing


@pytest.mark.integration
def test_a_spec_s_training_params_is_what_the_trainer_applies(tmp_path):
    _, first = train_fielded(
        tmp_path, lambda params, config, fraction: params.replace(respawn=config.respawn, crash_penalty=params.crash_penalty * fraction)
    )
    assert float(first["respawn"]) == 1.0 and float(first["crash_penalty"]) == 0.0


def test_parse_settings_types_and_one_line_refusals():
    got = parse_settings(["learning_rate=1e-3", "hidden=64,64", "anneal_lr=false", "ppo.respawn=yes"], ["ppo"])
    assert got == {"ppo": {"learning_rate": 1e-3, "hidden": (64, 64), "anneal_lr": False, "respawn": True}}
    assert parse_settings(["epsilon_decay_episodes=none"], ["dqn"]) == {"dqn": {"epsilon_decay_episodes": None}}
    both = parse_settings(["num_envs=4", "acktr.kl_clip=0.01"], ["ppo", "acktr", "dqn"])
    assert both == {"ppo": {"num_envs": 4}, "acktr": {"num_envs": 4, "kl_clip": 0.01}, "dqn": {"num_envs": 4}}
    for texts, message in (
        (["lr=1"], "no setting 'lr'; valid: activation,"),
        (["num_envs=four"], "ppo num_envs takes an integer"),
        (["hidden=a,b"], "takes comma-separated integers"),
        (["respawn=maybe"], "takes true or false"),
        (["acktr.kl_clip=1"], "trains ppo, not 'acktr'"),
        (["learning_rate"], "write NAME=VALUE"),
    ):
        with pytest.raises(WorldagentError, match=message):
            parse_settings(texts, ["ppo"])


def test_train_set_refuses_bad_settings_in_one_line(tmp_path):
    out = str(tmp_path / "run")
    assert one_line_error(runner.invoke(app, ["train", "racing", "--out", out, "--set", "lr=0.1"]), "no setting 'lr'", "learning_rate")
    assert one_line_error(runner.invoke(app, ["train", "racing", "--out", out, "--set", "num_envs=many"]), "num_envs takes an integer")
    assert one_line_error(runner.invoke(app, ["train", "racing", "--out", out, "--set", "num_envs=0"]), "num_envs=0")
    missing = runner.invoke(app, ["influence", "racing", "--agent", "driver", "--generator", out, "--select", "crash_rate > 0", "--set", "gamma=x"])
    assert one_line_error(missing, "gamma takes a number")  # before the missing generator is looked at
    assert not (tmp_path / "run").exists()


def test_reproduce_set_reaches_the_agents_of_its_algorithm():
    shown = runner.invoke(app, ["reproduce", "--preset", "tiny", "--set", "ppo.learning_rate=1e-3", "--set", "gamma=0.9", "--show"])
    assert shown.exit_code == 0, shown.output
    assert json.loads(shown.output)["settings"] == {"ppo": {"learning_rate": 1e-3, "gamma": 0.9}, "dqn": {"gamma": 0.9}}
    refused = runner.invoke(app, ["reproduce", "--preset", "tiny", "--env", "harvest", "--set", "ppo.learning_rate=1e-3", "--show"])
    assert one_line_error(refused, "trains dqn, not 'ppo'")
    assert one_line_error(runner.invoke(app, ["reproduce", "--preset", "tiny", "--set", "num_envs=0", "--show"]), "num_envs=0")


WARNING_APP = """
import warnings, typer
from worldagent.commands.console import friendly_errors, one_line_warning

@friendly_errors
def warn() -> None:
    warnings.warn("the default agent\\n   laps in only 10% of its episodes", stacklevel=2)
    warnings.warn("overflow", RuntimeWarning, stacklevel=2)

typer.run(warn)
"""


def test_commands_show_warnings_as_one_line():
    shown = subprocess.run([sys.executable, "-c", WARNING_APP], capture_output=True, text=True, timeout=120)
    assert shown.returncode == 0, shown.stderr
    assert shown.stderr.splitlines() == ["warning: the default agent laps in only 10% of its episodes", "warning (RuntimeWarning): overflow"]
    with pytest.warns(UserWarning, match="laps in only"):  # recording still works through a command
        friendly_errors(lambda: warnings.warn("laps in only 0%", stacklevel=2))()
    assert warnings.formatwarning is not one_line_warning  # restored after the command
