"""Presets of ``worldagent reproduce``: the budgets of each phase of the paper's pipeline.

Three presets, frozen dataclasses so a run directory can record exactly what ran. Their
budgets per environment are Python data in each environment's registration
(``EnvSpec.presets[name]``), so an environment registered with presets joins ``reproduce`` with
no edit here:

- ``paper``: the paper's budgets (§5.2–§6: 10,000 worlds, 10,000 racing / 5,000 harvest
  training episodes, CMA-ES population 21, 8 episodes per world, 1,000 random worlds). Search
  and influence budgets the paper does not state are ours (marked in the field docs). For a GPU.
- ``quick``: the main job (``docs/main-job.md``). Small budgets that finish both environments in under
  10 minutes on 2 CPU cores and still show every phenomenon: a high random mean beside a
  much lower minimum and a higher maximum, ES against BO against random search, and the
  influenced agents' metrics beside the default ones.
- ``tiny``: the whole pipeline in about a minute per environment (CI and tests); its numbers
  mean nothing, it only exercises every phase.

Every phase reads only its own slice of a preset (``phase_config``); a run directory compares
that slice with the one it finished with, so changing one budget re-runs only what depends on it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from worldagent.envs import registry
from worldagent.errors import WorldagentError
from worldagent.runs import PHASES  # the phases a run directory records (runs.py reads them too)

OPTIONAL_BUDGETS = (
    "compare_budget",
    "bo_budget",
    "influence_search_budget",
    "train_envs",
    "learning_starts",
    "atlas_budget",
    "failure_worlds",
)  # 0 / None allowed


@dataclass(frozen=True)
class EnvBudgets:
    """Budgets of one environment's phases.

    Attributes:
        worlds: procedurally generated worlds in the VAE's dataset (paper §5.2.1: 10,000).
        vae_epochs: VAE training epochs (ours: 25).
        episodes: training episodes of the agents (paper §5.3: racing 10,000, harvest 5,000).
        train_envs: environments stepped in parallel while training (0: the algorithm's default).
        atlas_budget: worlds the failure atlas's CMA-ME search evaluates (ours; 0 skips the atlas phase).
        failure_worlds: worlds Monte Carlo and importance sampling each sample to estimate the
            probability of ``spec.failure`` in the atlas phase (ours).
        learning_starts: harvest DQN: transitions per agent before learning (None: the default).
        random_worlds: worlds z ~ N(0, I) of the random evaluation (paper §6.1.1: 1,000).
        strategic_budget: worlds each CMA-ES search (min, max) may evaluate (ours).
        compare_budget: worlds per optimiser and seed in the ES / BO / random comparison (ours;
            0 skips the phase).
        compare_seeds: seeds of that comparison.
        bo_budget: worlds per seed for Bayesian optimisation in that comparison (0: ``compare_budget``).
            A BO suggestion costs a Gaussian-process fit, so the quick preset gives BO fewer
            worlds, as the paper found it needs (§6.1.3: "5x fewer samples").
        influence_candidates: random worlds scored to select the influenced training worlds (ours).
        influence_episodes: training episodes of each default and influenced agent.
        influence_eval_worlds: random worlds both agents are evaluated on (ours).
        influence_seeds: training seeds of the influencing experiment.
        influence_search_budget: extra evaluations searching for selectable worlds (ours).
        influence_search: that search: "cmaes" (the paper's optimiser) or "atlas" (CMA-ME, which
            collects many distinct worlds instead of revisiting one).
        options: env options of this preset's agents, over ``spec.reproduce_options`` (racing's
            paper preset: the paper's observation, ``observation="rays"``).
        algo: this env's training algorithm at this preset ("": ``spec.default_algorithm``;
            ``reproduce --algo`` overrides both).
        optimiser: the strategic phase's search optimiser ("": ``spec.optimiser``; a paper preset
            whose env departs from CMA-ES names ``"cmaes"``, the paper's).
        settings: ``{algo: {config field: value}}`` of this env's agents at this preset (ours), over the
            algorithm's defaults and the env's overrides; ``reproduce --set`` wins over them.
        influence_selection: the property of the influenced training worlds ("": the paper's,
            ``spec.selection``). Our racing agents crash 5–20× less often than the paper's (crash
            rate 0.005–0.07 against 0.11), so worlds with a crash rate above 0.5 are rare or
            absent: for the route PPO agent 2 of 1,000 random worlds, and a 2,100-world CMA-ES
            search found only 9 distinct tracks (agents trained on those failed: 3 seeds, crash
            rate 0.56, no laps); for the rays ACKTR agent none of 1,000 random worlds and none of
            a 2,100-world crash-maximising atlas (its worst: 2 crashes in 8), and 1 of all 10,000
            dataset tracks (``benchmarks/results/influence-racing.json``). The racing presets therefore select
            the worlds where the agent crashed at all (``"crash_rate > 0"``).
    """

    worlds: int
    vae_epochs: int
    episodes: int
    random_worlds: int
    strategic_budget: int
    compare_budget: int
    compare_seeds: tuple[int, ...]
    influence_candidates: int
    influence_episodes: int
    influence_eval_worlds: int
    influence_seeds: tuple[int, ...]
    influence_search_budget: int = 0
    influence_search: str = "cmaes"
    influence_selection: str = ""
    bo_budget: int = 0
    train_envs: int = 0
    learning_starts: int | None = None
    atlas_budget: int = 0
    failure_worlds: int = 0
    options: Mapping[str, Any] = field(default_factory=dict)
    algo: str = ""
    optimiser: str = ""
    settings: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)


@dataclass(frozen=True)
class Curriculum:
    """The curriculum every env's agent trains with (``reproduce --curriculum``; ``worldagent train`` takes the same).

    Attributes:
        name: a curriculum of ``curricula.curricula()``: ``dr`` (the default: the agent trains on
            the dataset's procedural worlds, as the paper's did) or an adaptive one (``plr``,
            ``accel``, ``target``), which draws latents z of the run's own G(z).
        target: the event or metric the curriculum scores episodes by (``--target``); None:
            learning potential, and for ``target`` each env's ``spec.failure``.
        maximize: with ``target`` a metric: train toward worlds where it is high (True) / low (False).
        settings: ``--curriculum-set``'s {setting: value} over the curriculum's defaults.
    """

    name: str = "dr"
    target: str | None = None
    maximize: bool | None = None
    settings: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Preset:
    """Everything ``worldagent reproduce`` needs to know, for every environment that has the preset.

    Attributes:
        name: the preset's name (the default run directory is ``runs/<name>``).
        description: one line on what it is for.
        envs: {env name: its budgets}, from ``EnvSpec.presets[name]`` of every registered env.
        seed: the seed of every phase (datasets, VAEs, training, searches).
        repeats: episodes per evaluated world (paper §5.2.2: 8).
        vae_hidden: encoder widths; the decoder is the transpose (paper §5.2.1: 1024, 512).
        vae_batch_size: VAE minibatch.
        algo: the training algorithm for every env whose ``spec.algorithms`` has it (``--algo``);
            None: each env's ``EnvBudgets.algo``, else its ``spec.default_algorithm``.
        settings: ``{algo: {config field: value}}`` set on every agent trained with ``algo``
            (``reproduce --set``, ``algorithms.parse_settings``), over the env's own settings, the budgets' ``settings`` and
            the budgets' ``train_envs`` / ``learning_starts``.
        curriculum: the curriculum of every env's agent (``reproduce --curriculum``); checked per
            env by ``check_curriculum`` before any phase runs.
        repair: the repair of every env's G(z) by name (``reproduce --repair``, ``EnvSpec.repairs``,
            e.g. ``open``); None: each env's default (the paper's ``nearest`` for racing and harvest).
        confirm: fresh episodes each reported world (strategic, compare) is replayed on
            (``analysis.confirm``; ours, not the paper's: it reports the found figure only).
        elite_confirm: fresh episodes each atlas elite is replayed on (the corrected archive).
        influence_confirm: fresh episodes each world of influence's selection is replayed on, only those
            that keep the property trained on (``influence.confirmation``); 0: the raw selection, as the paper.
        accept_generator: why a generator its quality gate rejects (``worlds.quality.gate``) is used
            anyway, recorded with the gate's verdict in the generator phase's outputs and in the
            manifest; None: the generator phase refuses it (``reproduce --accept-generator``). The
            tiny preset's toy budgets are such a reason.
    """

    name: str
    description: str
    envs: Mapping[str, EnvBudgets] = field(default_factory=dict)
    seed: int = 0
    repeats: int = 8
    vae_hidden: tuple[int, ...] = (1024, 512)
    vae_batch_size: int = 128
    algo: str | None = None
    settings: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    curriculum: Curriculum = field(default_factory=Curriculum)
    repair: str | None = None
    confirm: int = 64
    elite_confirm: int = 32
    influence_confirm: int = 32  # a selection is as many worlds as an atlas's elites
    accept_generator: str | None = None

    def __post_init__(self):
        if self.repeats < 1 or self.seed < 0:
            raise WorldagentError(f"repeats={self.repeats}, seed={self.seed}; repeats must be >= 1 and the seed >= 0.")
        if self.confirm < 1 or self.elite_confirm < 1:
            raise WorldagentError(f"confirm={self.confirm}, elite_confirm={self.elite_confirm}; replay reported worlds on at least 1 episode.")
        if self.influence_confirm < 0:
            raise WorldagentError(f"influence_confirm={self.influence_confirm}; pass 0 (the raw selection) or the fresh episodes per selected world.")
        if self.algo is not None and not any(self.algo in registry.get(env).algorithms for env in self.envs):
            known = sorted({a for env in self.envs for a in registry.get(env).algorithms})
            raise WorldagentError(f"algorithm {self.algo!r} trains none of {', '.join(self.envs)}; use one of: {', '.join(known)}.")
        for env, budgets in self.envs.items():
            small = [
                f.name
                for f in dataclasses.fields(budgets)
                if isinstance(getattr(budgets, f.name), int) and f.name not in OPTIONAL_BUDGETS and getattr(budgets, f.name) < 1
            ]
            if small:
                raise WorldagentError(f"preset {self.name!r}: {env} budgets {', '.join(small)} must be at least 1.")
            from worldagent.influence.experiment import SEARCHES

            if budgets.influence_search not in SEARCHES:
                raise WorldagentError(
                    f"preset {self.name!r}: {env} influence_search {budgets.influence_search!r}; use one of: {', '.join(SEARCHES)}."
                )
            spec = registry.get(env)
            spec.check_options(budgets.options)  # an unknown option is refused with the known ones
            if budgets.algo and budgets.algo not in spec.algorithms:
                raise WorldagentError(f"preset {self.name!r}: {env} trains with {', '.join(spec.algorithms)}, not {budgets.algo!r}.")
            if self.settings_of(env):  # a bad value is refused now, not after the phases before training
                from worldagent.agents.algorithms import training_config

                training_config(env, self.algo_of(env), budgets.episodes, options=self.options_of(env), **self.settings_of(env))

    def budgets(self, env: str) -> EnvBudgets:
        """The budgets of ``env``."""
        if env not in self.envs:
            raise WorldagentError(f"preset {self.name!r} has no budgets for {env!r}; use one of: {', '.join(self.envs)} or all.")
        return self.envs[env]

    def with_budgets(self, env: str, **changes) -> Preset:
        """This preset with some of ``env``'s budgets changed."""
        return replace(self, envs={**self.envs, env: replace(self.budgets(env), **changes)})

    def to_dict(self) -> dict:
        """JSON-able form (tuples as lists), as recorded in ``manifest.json``."""
        return json.loads(json.dumps({**dataclasses.asdict(self), "envs": {e: dataclasses.asdict(b) for e, b in self.envs.items()}}))

    def show(self) -> str:
        """The preset as indented JSON (``worldagent reproduce --show``)."""
        return json.dumps(self.to_dict(), indent=2)

    def with_algo(self, algo: str | None) -> Preset:
        """This preset with another training algorithm where an env has it (``--algo``)."""
        return self if algo is None else replace(self, algo=algo)

    def with_settings(self, settings: Mapping[str, Mapping[str, Any]]) -> Preset:
        """This preset with config fields set on every agent of an algorithm (``--set``; ``{algo: {field: value}}``)."""
        settings = {algo: dict(fields) for algo, fields in settings.items() if fields}
        return replace(self, settings=settings) if settings else self

    def with_generator_accepted(self, reason: str | None) -> Preset:
        """This preset with generators its gate rejects used anyway, for ``reason`` (``--accept-generator``; None: unchanged)."""
        return self if not reason else replace(self, accept_generator=reason)

    def with_repair(self, name: str | None) -> Preset:
        """This preset with every env's G(z) repaired by the repair called ``name`` (``--repair``; None: the defaults);
        ``check_repair`` refuses it for an env that has no such repair."""
        return self if name is None else replace(self, repair=name)

    def check_repair(self, env: str) -> None:
        """Refuse, in one line and before any work, a repair ``env`` does not have."""
        registry.get(env).repair_factory(self.repair)

    def with_curriculum(self, name: str = "dr", target: str | None = None, maximize: bool | None = None, settings: Mapping | None = None) -> Preset:
        """This preset with every env's agent trained with curriculum ``name`` (``--curriculum``, ``--target``,
        ``--maximize/--minimize``, ``--curriculum-set`` parsed by ``curricula.parse_curriculum_settings``)."""
        return replace(self, curriculum=Curriculum(name, target, maximize, dict(settings or {})))

    def curriculum_of(self, env: str) -> dict[str, Any] | None:
        """What ``env``'s agent phase records of its curriculum (None for ``dr``, so earlier runs still match):
        name, settings and, where there is one, the target (``target``'s default: ``spec.failure``)."""
        chosen = self.curriculum
        if chosen.name == "dr" and not chosen.settings and chosen.target is None and chosen.maximize is None:
            return None
        target = chosen.target if chosen.target is not None or chosen.name != "target" else (registry.get(env).failure or None)
        return {
            "name": chosen.name,
            "settings": dict(chosen.settings),
            **({"target": target} if target is not None else {}),
            **({"maximize": chosen.maximize} if chosen.maximize is not None else {}),
        }

    def check_curriculum(self, env: str) -> str | None:
        """Refuse, in one line and before any work, a curriculum ``worldagent train`` would refuse for ``env``;
        returns ``train``'s warning when its buffer cannot start replaying early in ``env``'s budget, else None."""
        from worldagent.curricula import late_replay_warning

        request = self.curriculum_of(env)
        if request is None:
            return None
        return late_replay_warning(make_curriculum_of(env, request, None), self.budgets(env).episodes)

    def settings_of(self, env: str) -> dict[str, Any]:
        """The config fields this preset sets on ``env``'s agents (those of its algorithm): the budgets' own
        (``EnvBudgets.settings``), then ``--set``'s."""
        algo = self.algo_of(env)
        return {**self.budgets(env).settings.get(algo, {}), **self.settings.get(algo, {})}

    def phase_config(self, env: str, phase: str) -> dict:
        """The settings phase ``phase`` of ``env`` depends on (compared when a run resumes)."""
        b = self.budgets(env)
        options = self.options_of(env)
        table = {
            "dataset": {"worlds": b.worlds},
            "generator": {
                "epochs": b.vae_epochs,
                "hidden": list(self.vae_hidden),
                "batch_size": self.vae_batch_size,
                **({"repair": self.repair} if self.repair else {}),  # absent for the default: earlier runs still match
            },
            "agent": {
                "algo": self.algo_of(env),
                "episodes": b.episodes,
                "train_envs": b.train_envs,
                "learning_starts": b.learning_starts,
                **({"options": options} if options else {}),
                **({"settings": self.settings_of(env)} if self.settings_of(env) else {}),  # absent when none: earlier runs still match
                **({"curriculum": self.curriculum_of(env)} if self.curriculum_of(env) else {}),  # absent for dr, likewise
            },
            "random": {"worlds": b.random_worlds, "repeats": self.repeats},
            "strategic": {"budget": b.strategic_budget, "repeats": self.repeats, "optimiser": self.optimiser_of(env)},
            "compare": {
                "budget": b.compare_budget,
                "bo_budget": b.bo_budget or b.compare_budget,
                "seeds": list(b.compare_seeds),
                "repeats": self.repeats,
                "optimisers": ["cmaes", "bo", "random"],
            },
            "influence": {
                "selection": self.selection(env),
                "candidates": b.influence_candidates,
                "episodes": b.influence_episodes,
                "eval_worlds": b.influence_eval_worlds,
                "seeds": list(b.influence_seeds),
                "search_budget": b.influence_search_budget,
                **({"search": b.influence_search} if b.influence_search != "cmaes" else {}),  # runs made before the field still match
                "repeats": self.repeats,
                "algo": self.algo_of(env),
                **({"settings": self.settings_of(env)} if self.settings_of(env) else {}),
                **({"confirm": self.influence_confirm} if self.influence_confirm else {}),  # absent unconfirmed: earlier runs still match
            },
            "atlas": {
                "budget": b.atlas_budget,
                "failure": registry.get(env).failure,
                "failure_worlds": b.failure_worlds,
                "repeats": self.repeats,
            },
        }
        if phase not in table:
            raise WorldagentError(f"unknown phase {phase!r}; use one of: {', '.join(PHASES)}.")
        return {"seed": self.seed, **table[phase]}

    def full_phase_config(self, env: str, phase: str) -> dict:
        """``phase_config`` as JSON holds it, with what it leaves out when it is the default (so that earlier runs
        still match) written in: every env option (``spec.check_options``), the env's default repair, the
        influence search's default and no confirmation of the influence selection. What the report compares."""
        spec, filled = registry.get(env), self.phase_config(env, phase)
        if phase == "agent":
            filled["options"] = spec.check_options(filled.get("options") or {})
        if phase == "generator":
            filled.setdefault("repair", spec.default_repair)
        if phase == "influence":
            filled.setdefault("search", EnvBudgets.influence_search)
            filled.setdefault("confirm", 0)
        return json.loads(json.dumps(filled, default=list))

    def selection(self, env: str) -> str:
        """The influencing experiment's selection of ``env`` (``spec.selection`` unless the budgets override it)."""
        return self.budgets(env).influence_selection or registry.get(env).selection

    def algo_of(self, env: str) -> str:
        """The training algorithm of ``env``'s agents: ``algo`` where the env has it, else the budgets', else the env's default."""
        spec = registry.get(env)
        return self.algo if self.algo in spec.algorithms else (self.budgets(env).algo or spec.default_algorithm)

    def optimiser_of(self, env: str) -> str:
        """The search optimiser of ``env``'s strategic phase: the budgets' where they name one, else the env's."""
        return self.budgets(env).optimiser or registry.get(env).optimiser

    def options_of(self, env: str) -> dict[str, Any]:
        """The env options of ``env``'s agents: ``spec.reproduce_options`` with the budgets' on top."""
        return {**registry.get(env).reproduce_options, **self.budgets(env).options}


def make_curriculum_of(env: str, request: dict, worlds: Any) -> Any:
    """The curriculum ``request`` (``Preset.curriculum_of``) over ``worlds``, checked as ``worldagent train`` checks it.

    ``worlds`` None only checks the request: the curriculum is built over a placeholder G(z), so
    every refusal of ``train`` (an unknown name or setting, a value out of range, ``--maximize``
    without ``--target``, a target the env cannot score, ``dr`` given settings) comes from the
    same ``curricula`` code before any phase runs.
    """
    from worldagent.agents.distributions import LatentWorlds
    from worldagent.curricula import check_request, make_curriculum
    from worldagent.curricula.scores import requested_target

    settings = dict(request.get("settings", {}))
    check_request(request["name"], settings, True)  # the agent phase draws G(z) of the run's generator: latents there are
    scoring = requested_target(env, request.get("target"), request.get("maximize"))
    return make_curriculum(request["name"], LatentWorlds(None) if worlds is None else worlds, settings, scoring)


# name -> (description, settings other than budgets); budgets come from each EnvSpec.presets[name]
SETTINGS = {
    "tiny": (
        "Every phase at a toy budget (CI and tests); the numbers mean nothing.",
        {
            "repeats": 2,
            "vae_hidden": (64, 32),
            "vae_batch_size": 32,
            "confirm": 4,
            "elite_confirm": 2,
            "influence_confirm": 0,
            # a VAE of a few epochs on a few hundred worlds has not learnt its worlds yet (ued_maze: 0 of 10 latent
            # dimensions active after 3 epochs, held-out NLL 663 nats against the mean world's 58)
            "accept_generator": "expected at the tiny preset's toy budgets (a few VAE epochs on a few hundred worlds)",
        },
    ),
    "quick": ("Small budgets that finish both environments in under 10 minutes on 2 CPU cores and still show every phenomenon.", {}),
    "paper": (
        "The paper's budgets (10,000 worlds, 10,000 / 5,000 training episodes, population 21, 8 repeats, 1,000 random worlds); for a GPU.",
        {},
    ),
}


def env_budgets(preset_name: str) -> dict[str, EnvBudgets]:
    """{env: budgets} of every registered environment that has preset ``preset_name``."""
    found = {}
    for env in registry.names():
        values = registry.get(env).presets.get(preset_name)
        if values is not None:
            try:
                found[env] = EnvBudgets(**values)
            except TypeError as error:
                raise WorldagentError(f"{env}'s preset {preset_name!r} is malformed ({error}); see reproduce.presets.EnvBudgets.") from None
    return found


def paper_phase_config(env: str, phase: str) -> dict | None:
    """The ``paper`` preset's ``full_phase_config`` of ``phase`` for ``env``; None: the env has no paper preset."""
    if "paper" not in registry.get(env).presets:
        return None
    return get_preset("paper").full_phase_config(env, phase)


def get_preset(name: str) -> Preset:
    """The preset called ``name``, with the budgets the registered environments give it."""
    if name not in SETTINGS:
        raise WorldagentError(f"unknown preset {name!r}; use one of: {', '.join(SETTINGS)}.")
    description, settings = SETTINGS[name]
    return Preset(name=name, description=description, envs=env_budgets(name), **settings)
