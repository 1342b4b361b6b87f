"""Options the commands share: the environment argument, ``--option``, ``--agent``, and the checks of
counts, seeds, metrics and run directories that every command runs before anything heavy loads.

Help texts that list environments are built from the registry when a command registers, so an
environment registered by a plugin shows up in ``--help`` with no edit here.
"""

from __future__ import annotations

import os
from pathlib import Path

import typer

from worldagent.envs import registry
from worldagent.errors import WorldagentError

AGENT_HELP = (
    "The agent: a `worldagent train` run directory (or the agent directory in it), a scripted policy (`worldagent envs` lists them), "
    "a .onnx model, a Stable-Baselines3 .zip, or module:function (a Python callable obs batch -> actions, from the working directory)."
)
STOCHASTIC_HELP = "External agents that return logits sample their action (with the episode's key) instead of taking the argmax."
GENERATOR_HELP = "Generator directory (from `worldagent generator train`)."
OPTION_HELP = "An environment option NAME=VALUE, e.g. tagger=0 for harvest (repeatable; `worldagent envs` lists them)."
QUIET_HELP = "No progress bars."


def env_help() -> str:
    """``Environment: racing, harvest (`worldagent envs` describes them).`` from the registry."""
    return f"Environment: {', '.join(registry.names())} (`worldagent envs` describes them)."


def metric_help() -> str:
    """The metrics each registered environment offers, for ``--metric`` / ``--objective``."""
    listed = "; ".join(f"{name}: {'|'.join(registry.get(name).metrics.names)}" for name in registry.names())
    return f"Metric: reward (the environment's main one), or {listed}."


def env_argument():
    """The ``ENV`` argument of a command (evaluated when the command registers)."""
    return typer.Argument(..., help=env_help())


def option_flag():
    """The repeatable ``--option NAME=VALUE``."""
    return typer.Option([], "--option", help=OPTION_HELP)


SET_HELP = (
    "A training setting NAME=VALUE: any field of the algorithm's config (repeatable), e.g. --set learning_rate=1e-3 --set hidden=64,64; "
    "applied over the algorithm's defaults and the environment's departures from them. The resolved config is recorded in the run directory. "
    "PPO with memory, for worlds seen in part: --set recurrent=lstm (or gru; --set memory_size=256)."
)


def set_flag(help: str = SET_HELP):
    """The repeatable ``--set NAME=VALUE`` (a field of the training algorithm's config)."""
    return typer.Option([], "--set", metavar="NAME=VALUE", help=help)


def stochastic_flag():
    """``--stochastic``: external agents sample from their logits."""
    return typer.Option(False, "--stochastic", help=STOCHASTIC_HELP)


def backend_flag():
    """``--backend``: where campaigns evaluate their world batches."""
    return typer.Option("local", "--backend", help="Where world batches are evaluated: local (every local device) or ray (extra `ray`).")


def ray_address_flag():
    """``--ray-address``: a Ray cluster to join."""
    return typer.Option(None, "--ray-address", help="A running Ray cluster to join (`ray start --head` prints it); default: start a local one.")


def backend(name: str, address: str | None):
    """The backend of ``--backend`` / ``--ray-address``."""
    from worldagent.evaluation.backends import make_backend

    return make_backend(name, address)


def curricula_help() -> str:
    """``--curriculum``'s help: the curricula there are."""
    from worldagent.curricula import curricula

    return ", ".join(curricula()) + " (dr, every world afresh, is the default; see docs/curriculum.md)."


def curriculum_set_flag():
    """``--curriculum-set NAME=VALUE`` (repeatable), naming the settings there are."""
    import dataclasses

    from worldagent.curricula.replay import Settings

    names = ", ".join(f.name for f in dataclasses.fields(Settings))
    return typer.Option(
        [], "--curriculum-set", metavar="NAME=VALUE", help=f"A curriculum setting (repeatable): {names}; defaults in docs/curriculum.md."
    )


def command_setup(
    env: str, agent: str, generator, option: list[str], *, stochastic: bool, repeats: int, backend_name: str, ray_address, greedy: bool = False
):
    """``experiments.setup`` of a command's agent, generator, ``--option``, ``--backend`` and ``--ray-address``."""
    from worldagent import experiments

    return experiments.setup(
        env,
        agent,
        generator,
        options=given_options(env, option),
        greedy=greedy,
        stochastic=stochastic,
        repeats=repeats,
        backend=backend(backend_name, ray_address),
    )


def env_options(env: str, texts: list[str]) -> dict:
    """The options of ``env`` parsed from ``--option`` texts (checked, defaults filled in)."""
    return registry.get(env).parse_options(list(texts))


def given_options(env: str, texts: list[str]) -> dict:
    """Only the options ``--option`` names (parsed, checked): ``experiments.setup`` fills the rest
    from the agent's own (a saved agent records those it trained with), then the defaults."""
    return registry.get(env).parse_options(list(texts), fill=False)


# The most of each count a command accepts: far above any real use (the paper: 8 episodes per
# world, 10,000 worlds, budgets of a few thousand), low enough that a stray digit fails at once
# instead of running for days or exhausting memory.
COUNT_CAPS = {
    "repeats": 1_000,
    "worlds": 10_000_000,
    "budget": 10_000_000,
    "random_worlds": 10_000_000,
    "seeds": 1_000,
    "samples": 1_000_000,
    "candidates": 10_000_000,
    "eval_worlds": 10_000_000,
    "search_budget": 10_000_000,
}
TRAINING_EPISODES_CAP = 10_000_000  # training episodes of one agent (1,000x the paper's 10,000)
DATASET_CAP = 1_000_000  # worlds in a dataset (100x the paper's; racing's take about 12 GB)
PICTURE_CAP = 256  # worlds or episodes drawn on one picture (a 16 x 16 sheet)
MAX_SEED = 2**31 - 1  # seeds reach jax.random.key, which keeps 32 bits, and worlds SEED + i must too


def check_counts(caps: dict[str, int] | None = None, **counts: int) -> None:
    """Each named count must be at least 1 and at most its cap (``caps``, else ``COUNT_CAPS``);
    one-line error naming the option."""
    for option, value in counts.items():
        flag = f"--{option.replace('_', '-')}"
        if value < 1:
            raise WorldagentError(f"{flag} is {value}; it must be at least 1.")
        cap = {**COUNT_CAPS, **(caps or {})}.get(option)
        if cap is not None and value > cap:
            raise WorldagentError(f"{flag} is {value:,}, above the cap of {cap:,}; use at most {cap:,}.")


def check_seed(seed: int, option: str = "--seed") -> None:
    """A seed is an integer from 0 to ``MAX_SEED`` (one-line error naming the option)."""
    if not 0 <= seed <= MAX_SEED:
        raise WorldagentError(f"{option} is {seed}; seeds are integers from 0 to {MAX_SEED:,}.")


def check_metric(env: str, name: str) -> str:
    """The canonical metric ``name`` names for ``env`` ("reward": the main one); unknown names are refused."""
    spec = registry.get(env)
    return spec.metrics.resolve(name, spec.name)


def check_optimiser(name: str) -> None:
    """``--optimiser``: one of the search optimisers."""
    from worldagent.search.optimisers import OPTIMISERS

    if name not in OPTIMISERS:
        raise WorldagentError(f"unknown optimiser {name!r}; use one of: {', '.join(OPTIMISERS)}.")


def optimiser_help() -> str:
    """``--optimiser``: the choices and each registered env's default (``EnvSpec.optimiser``)."""
    defaults = ", ".join(f"{name}: {registry.get(name).optimiser}" for name in registry.names())
    return f"cmaes (the paper's), bo or random; default: the env's ({defaults})."


def budget_help() -> str:
    """``--budget``: its default per optimiser (``search.optimisers.DEFAULT_BUDGETS``)."""
    from worldagent.search.optimisers import DEFAULT_BUDGETS

    defaults = ", ".join(f"{budget:,} with {name}" for name, budget in DEFAULT_BUDGETS.items())
    return f"Worlds to evaluate (CMA-ES rounds up to whole generations); default {defaults} (BO's cost grows with the worlds seen)."


def search_settings(env: str, optimiser: str | None, budget: int | None) -> tuple[str, int]:
    """``--optimiser`` and ``--budget`` of a search, each defaulted when unset: the env's optimiser
    (``EnvSpec.optimiser``), that optimiser's budget (``search.optimisers.DEFAULT_BUDGETS``)."""
    from worldagent.envs import registry
    from worldagent.search.optimisers import DEFAULT_BUDGETS

    optimiser = registry.get(env).optimiser if optimiser is None else optimiser
    check_optimiser(optimiser)
    return optimiser, DEFAULT_BUDGETS[optimiser] if budget is None else budget


def check_training_episodes(episodes: int | None) -> None:
    """``--episodes`` of training: unset (the algorithm's budget), or from 1 to ``TRAINING_EPISODES_CAP``."""
    if episodes is not None:
        check_counts(caps={"episodes": TRAINING_EPISODES_CAP}, episodes=episodes)


def check_store(store_file: Path) -> None:
    """A run store that already exists, before anything heavy loads: writable, a store, and intact
    (a rerun resumes from it). One that does not exist yet passes."""
    from worldagent.store import RunStore

    store_file = Path(store_file)
    if not store_file.exists():
        return
    if not os.access(store_file, os.W_OK):  # SQLite would open it read-only and fail at the first write
        raise WorldagentError(f"{store_file} is read-only; make it writable or choose another --out.")
    with RunStore(store_file, create=False) as store:
        store.check_intact()


def check_run_dir(out: Path) -> None:
    """A run directory ``--out``, before anything heavy loads: it can be written, and a store
    already in it opens and is intact (a rerun resumes from it)."""
    from worldagent.files import check_writable
    from worldagent.store import STORE_FILE

    check_writable(out, folder=True)
    check_store(Path(out) / STORE_FILE)


def algorithm(env: str, algo: str | None) -> str:
    """``algo``, or the env's default algorithm; one the env does not train with is refused."""
    spec = registry.get(env)
    algo = algo or spec.default_algorithm
    if algo not in spec.algorithms:
        raise WorldagentError(f"unknown algorithm {algo!r} for {spec.name}; use one of: {', '.join(spec.algorithms)}.")
    return algo


def algo_help() -> str:
    """``--algo`` help: each environment's algorithms, the default first."""
    listed = "; ".join(f"{name}: {', '.join(registry.get(name).algorithms)}" for name in registry.names())
    return f"Training algorithm (default: the environment's first): {listed}."
