"""The environment registry (DESIGN.md "EnvSpec"): everything the upper layers ask about an env.

Every layer above ``envs/`` looks an environment up here instead of comparing its name::

    from worldagent.envs import registry

    spec = registry.get("racing")
    env, params = spec.make({"tagger": 0})         # options, checked against spec.options
    worlds = spec.generate(np.arange(16))          # the procedural generator
    spec.metrics.resolve("reward")                 # -> "return"

Racing and harvest register themselves in ``envs/<name>/spec.py``. Third-party packages
register through the entry-point group ``worldagent.envs`` (each entry point names an
``EnvSpec`` or a zero-argument callable returning one), so a new environment is a new folder or
package and no edit elsewhere. Tests register toy environments with ``register`` directly.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from worldagent.errors import WorldagentError

ENTRY_POINT_GROUP = "worldagent.envs"
DEFAULT_REPAIR = "default"  # the name of an env's only repair
BUILTIN = ("worldagent.envs.racing.spec", "worldagent.envs.harvest.spec")


@dataclass(frozen=True)
class EnvOption:
    """An option of ``EnvSpec.make`` (e.g. which harvest agent may TAG).

    Attributes:
        name: the key in the options mapping (CLI: ``--option NAME=VALUE``).
        help: one line for ``--help`` and ``worldagent envs``.
        parse: ``text -> value`` for values given as strings on the command line; raises
            ``WorldagentError`` (or ``ValueError``) on bad text.
        default: the value when the option is not given.
    """

    name: str
    help: str
    parse: Callable[[str], Any] = str
    default: Any = None


class ScriptedPolicy(NamedTuple):
    """A hand-written policy as the env folder defines it (``agents`` wraps it into a ``Policy``).

    Attributes:
        params: its parameters (a pytree, or None).
        act: ``act(params, obs, key, state) -> action`` (pure JAX).
        privileged: True when ``act`` reads the env ``state`` instead of only ``obs``.
    """

    params: Any
    act: Callable
    privileged: bool = False


@dataclass(frozen=True)
class Metrics:
    """What an environment measures per episode, and how the upper layers use it.

    Attributes:
        main: the paper's main metric, what ``reward`` means (racing return, harvest group reward).
        names: every per-episode metric a search or selection may use (``env.metrics`` plus derived).
        aliases: other names users may write (e.g. ``crash_rate`` for ``crashed``).
        derive: ``(metrics {name: array}, params) -> metrics`` adding metrics computed from others.
        bounds: ``params -> (low, high)`` of the main metric for normalising it to [0, 1] (paper §6);
            None: normalised by the largest single-episode value of the run.
        compared: the metrics an influencing experiment compares (paper Figure 8).
        highlighted: metrics reports show beside the main one (rates: mean over episodes).
        descriptors: ``name -> (world -> float)`` features of a world (for quality-diversity search).
        default_descriptors: the descriptors a QD archive uses unless told otherwise.
        meanings: ``name -> what it measures``, in a line a newcomer reads (the explorer's tooltips and legends).
    """

    main: str
    names: tuple[str, ...]
    aliases: Mapping[str, str] = field(default_factory=dict)
    derive: Callable[[dict, Any], dict] | None = None
    bounds: Callable[[Any], tuple[float, float]] | None = None
    compared: tuple[str, ...] = ()
    highlighted: tuple[str, ...] = ()
    descriptors: Mapping[str, Callable[[Any], float]] = field(default_factory=dict)
    default_descriptors: tuple[str, ...] = ()
    meanings: Mapping[str, str] = field(default_factory=dict)

    def resolve(self, name: str, env: str = "this environment") -> str:
        """The canonical metric for ``name`` ("reward" is ``main``); unknown names are refused."""
        canonical = self.main if name == "reward" else self.aliases.get(name, name)
        if canonical not in self.names:
            known = ", ".join(("reward", *self.names, *self.aliases))
            raise WorldagentError(f"{env} has no metric {name!r}; use one of: {known}.")
        return canonical

    def with_derived(self, metrics: dict, params: Any) -> dict:
        """``metrics`` with the derived ones added."""
        return metrics if self.derive is None else self.derive(metrics, params)

    def normalise(self, values, params: Any, best_episode: float | None = None) -> np.ndarray:
        """Main-metric values scaled to [0, 1]: by ``bounds``, or by ``best_episode`` (the run's best)."""
        values = np.asarray(values, np.float64)
        if self.bounds is not None:
            low, high = self.bounds(params)
            return np.clip((values - low) / (high - low), 0.0, 1.0)
        if not best_episode or not np.isfinite(best_episode) or best_episode <= 0:
            return np.full(values.shape, np.nan)
        return values / best_episode


@dataclass(frozen=True)
class Pictures:
    """How an environment draws its worlds.

    Attributes:
        world: ``(world, size) -> PIL.Image`` one unbatched world, ``size`` pixels square.
        episodes: ``(matplotlib axis, world, episodes) -> None``: the world with the replayed
            episodes' trajectories (``evaluation.trajectories.Episodes``) on it.
        sheet: ``(batched worlds, path) -> path``: many worlds on one PNG (``worldagent worlds``).
        locate: ``(positions f[..., P], world, size) -> f[..., 2]``: where positions as ``trace``
            records them fall on ``world(world, size)``, as pixel (x, y); the explorer animates
            episodes with it (None: it shows ``episodes``' still picture instead).
        marks: ``(env, state) -> {kind: (positions [K, P], shown bool[K])}``: what else the
            explorer's animation draws at each step besides the agents (harvest: the apples, the
            TAG beams, where tagged-out agents were hit), recorded at every step of its replay as
            ``trace`` is; positions as ``trace`` records them (``locate`` places them), K fixed
            per kind, ``shown`` the ones there now. None: the agents only.
        mark_styles: ``kind -> {"shape": "dot" | "square" | "ring", "colour": CSS colour,
            "radius": fraction of the picture's side, "label": what it means}``: how the animation
            draws each kind, and its line in the explorer's legend (default label: the kind).
        legend: ``CSS colour -> what it means`` on ``world``'s picture (harvest: walls, apples,
            spawn corners), the explorer's legend beside the picture; empty: none shown.
        agents: names of the agents ``trace`` records, in its order (the legend of their trails);
            empty: "agent 1", "agent 2", ... (one agent: each episode has its own colour).
        agent_colours: the CSS colour of each agent of ``agents``, the one ``episodes`` draws it in, so
            the explorer's animation and the report's figures agree; empty: the explorer picks.
        outcomes: ``per-episode metric -> style`` (as ``mark_styles``, shape "cross" too): the mark
            drawn at each agent's last position when the episode's metric is non-zero (racing: a
            red cross where a crash ended it).
    """

    world: Callable[[Any, int], Any]
    episodes: Callable[[Any, Any, Any], None] | None = None
    sheet: Callable[[Any, Any], Any] | None = None
    locate: Callable[[Any, Any, int], Any] | None = None
    marks: Callable[[Any, Any], Mapping[str, tuple[Any, Any]]] | None = None
    mark_styles: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    legend: Mapping[str, str] = field(default_factory=dict)
    agents: tuple[str, ...] = ()
    agent_colours: tuple[str, ...] = ()
    outcomes: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)


@dataclass(frozen=True)
class EnvSpec:
    """One environment, as every layer above ``envs/`` sees it.

    Attributes:
        name: the registry key ("racing").
        description: one line for ``worldagent envs``.
        make: ``options -> (env, params)``; options are already checked and defaulted.
        options: the options ``make`` takes.
        world_type: the world dataclass (a ``flax.struct.dataclass`` of fixed-shape arrays).
        generate: the procedural generator, ``seeds int64[N] -> batched world`` (numpy).
        cells: ``batched world -> uint8[N, D]``, the VAE's binary input.
        cell_shape: one world's cells before flattening (pictures, the VAE's output).
        repair: ``(dataset, config) -> Repair``: the step that makes decoded cells a valid world
            (paper §4.2), the default one. A ``Repair`` is a pytree with ``__call__(logits f32[B, D])
            -> worlds[B]`` (pure, jittable) and a JSON-able ``config`` dict that rebuilds it
            (``generator.json``).
        repairs: ``name -> (dataset, config) -> Repair``: the repairs a generator may be trained
            with by name (``generator train --repair NAME``), ``repair`` among them; e.g. racing's
            ``nearest`` (the paper's: G(z) returns dataset worlds only) and ``open`` (new valid
            worlds). Empty: ``repair`` alone, called ``default``.
        metrics: see ``Metrics``.
        trace: ``state -> (positions, present)``: where the agents are (to draw trajectories).
        pictures: see ``Pictures``.
        scripted: ``name -> ((env, params) -> ScriptedPolicy)``: hand-written agents.
        algorithms: training algorithms that fit this env (first: the default).
        algorithm_overrides: ``algo -> {config field: value}``: this env's departures from an
            algorithm's defaults (which are the algorithm's own, e.g. PPO ``reward_scale=1``,
            ``respawn=False``), whatever the options (racing: ``reward_scale=0.01``, ``respawn``).
        option_overrides: ``(algo, options) -> {config field: value}``: departures that depend on
            the env options, applied after ``algorithm_overrides`` (racing: an agent without the
            route sensor learns with quadratic inputs and a crash warm-up); None: none. The
            commands read both through ``training_settings``; ``--set`` overrides them.
        training_params: ``(params, config, fraction) -> params``: the env params a learner
            trains under, given its algorithm config and ``fraction`` (f32, traced) of its episode
            budget done; trainers call it on every update. Only the env knows which of its
            params training changes (racing: respawn-on-crash as ``config.respawn``, the crash
            penalty ramped over ``config.crash_warmup``). None: training uses ``params`` as they are.
        presets: ``preset name -> {budget field: value}``: the budgets of ``worldagent reproduce``.
        reproduce_options: the ``make`` options ``worldagent reproduce`` uses (harvest: tagger 0).
        selection: the paper's influencing selection (``"crash_rate > 0.5"``).
        training_check: ``{metric: mean over evaluated worlds} -> ""`` when a trained agent
            behaves as one that learnt, else a few words on how it failed (racing: it never laps,
            i.e. it parks or crashes); influencing warns and the report flags such an agent.
        failure: the event that counts as a failure by default (the selection grammar): the
            failing threshold of ``worldagent atlas`` and the event of ``failure-rate`` in
            ``worldagent reproduce`` ("" where the env names none).
        paper: the paper's figures, for the report's "ours vs paper" table (key -> value).
        episode_note: ``episodes' metrics {name: [E]} -> str``: a few words on how episodes ended.
        raw_decode: ``logits f32[B, D] -> worlds`` without repair (thresholded cells), for the
            generator's "valid before repair" figure; None when cells do not determine a world.
        world_sets: ``name -> () -> batched world`` (numpy, leading axis N): named sets of worlds
            agents are scored on as they are, e.g. held-out evaluation sets such as the UED maze
            prefabs (``worldagent evaluate worlds ENV --worlds NAME``; ``worldagent check`` checks
            every world). Built on demand, so a large set costs nothing until asked for. Empty: none.
        generator_params: ``batched worlds -> {parameter: f[N]}``: the procedural generator's own
            draws as read back off its worlds (racing: its 20 checkpoint draws), for comparing their
            spread under G(z) with fresh worlds' (``worlds.coverage``); None where they cannot be
            read back cheaply and defensibly.
        optimiser: the search optimiser ``strategic`` and ``search`` use unless told (``--optimiser``),
            and ``reproduce``'s strategic phase outside the paper preset: the paper's ``cmaes``, or the
            one ``benchmarks/noisy_search.py`` found lower worlds with on fresh episodes at equal episode
            budgets (harvest: ``bo``, in 5 of 5 seeds).
    """

    name: str
    description: str
    make: Callable[[Mapping[str, Any]], tuple[Any, Any]]
    world_type: type
    generate: Callable[[np.ndarray], Any]
    cells: Callable[[Any], np.ndarray]
    cell_shape: tuple[int, ...]
    repair: Callable[[Any, Mapping[str, Any]], Any]
    metrics: Metrics
    trace: Callable[[Any], tuple[Any, Any]]
    pictures: Pictures
    options: tuple[EnvOption, ...] = ()
    scripted: Mapping[str, Callable[[Any, Any], ScriptedPolicy]] = field(default_factory=dict)
    algorithms: tuple[str, ...] = ()
    algorithm_overrides: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    option_overrides: Callable[[str, Mapping[str, Any]], Mapping[str, Any]] | None = None
    training_params: Callable[[Any, Any, Any], Any] | None = None
    presets: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    reproduce_options: Mapping[str, Any] = field(default_factory=dict)
    selection: str = ""
    failure: str = ""
    training_check: Callable[[Mapping[str, float]], str] | None = None
    paper: Mapping[str, float] = field(default_factory=dict)
    episode_note: Callable[[dict], str] | None = None
    raw_decode: Callable[[Any], Any] | None = None
    repairs: Mapping[str, Callable[[Any, Mapping[str, Any]], Any]] = field(default_factory=dict)
    world_sets: Mapping[str, Callable[[], Any]] = field(default_factory=dict)
    generator_params: Callable[[Any], Mapping[str, np.ndarray]] | None = None
    optimiser: str = "cmaes"

    @property
    def default_algorithm(self) -> str:
        """The algorithm every command trains with unless told otherwise."""
        if not self.algorithms:
            raise WorldagentError(f"{self.name} names no training algorithm; register it with algorithms=(...).")
        return self.algorithms[0]

    @property
    def cell_count(self) -> int:
        return int(np.prod(self.cell_shape))

    # -- repairs ----------------------------------------------------------------------------

    @property
    def repair_names(self) -> tuple[str, ...]:
        """The names ``generator train --repair NAME`` takes, the default's first."""
        return (self.default_repair, *(name for name in self.repairs if name != self.default_repair))

    @property
    def default_repair(self) -> str:
        """The name of ``repair`` (``default`` when it has none in ``repairs``)."""
        return next(
            (name for name, make in self.repairs.items() if make == self.repair), DEFAULT_REPAIR
        )  # == : bound classmethods are new objects each time

    def repair_factory(self, name: str | None = None) -> Callable[[Any, Mapping[str, Any]], Any]:
        """The repair called ``name`` (None or ``default``: the default; a generator saved before its env named
        its repairs recorded ``default``); unknown names list the known ones."""
        if name is None or name in (self.default_repair, DEFAULT_REPAIR):
            return self.repair
        if name not in self.repairs:
            raise WorldagentError(f"{self.name} has no repair {name!r}; use one of: {', '.join(self.repair_names)}.")
        return self.repairs[name]

    # -- options -----------------------------------------------------------------------------

    def check_options(self, options: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """``options`` with defaults filled in; unknown names are refused with the known ones."""
        options = dict(options or {})
        known = {option.name: option for option in self.options}
        unknown = sorted(set(options) - set(known))
        if unknown:
            listed = ", ".join(known) or "none"
            raise WorldagentError(f"{self.name} has no option {unknown[0]!r}; its options: {listed}.")
        return {name: options.get(name, option.default) for name, option in known.items()}

    def parse_options(self, texts: list[str] | tuple[str, ...], fill: bool = True) -> dict[str, Any]:
        """Options from ``NAME=VALUE`` strings (the CLI's ``--option``), parsed and checked;
        ``fill=False`` leaves out those not given (a saved agent's own options fill them)."""
        known = {option.name: option for option in self.options}
        options = {}
        for text in texts:
            name, sep, value = text.partition("=")
            name = name.strip()
            if not sep or not name:
                raise WorldagentError(f"--option {text!r}: write NAME=VALUE, e.g. --option {next(iter(known), 'name')}=...")
            if name not in known:
                self.check_options({name: None})  # raises, listing the known options
            try:
                options[name] = known[name].parse(value.strip())
            except ValueError as error:
                raise WorldagentError(f"--option {text!r}: {error}; {known[name].help}") from None
        return self.check_options(options) if fill else options

    def make_env(self, options: Mapping[str, Any] | None = None) -> tuple[Any, Any]:
        """``(env, params)`` for ``options`` (checked, defaults filled in)."""
        return self.make(self.check_options(options))

    # -- training ----------------------------------------------------------------------------

    def training_settings(self, algo: str, options: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """This env's departures from ``algo``'s default config for ``options`` (checked, defaults
        filled in): ``algorithm_overrides[algo]``, then ``option_overrides(algo, options)`` on top."""
        tuned = self.option_overrides(algo, self.check_options(options)) if self.option_overrides else {}
        return {**self.algorithm_overrides.get(algo, {}), **tuned}

    # -- worlds ------------------------------------------------------------------------------

    def world_to_arrays(self, world: Any) -> dict[str, np.ndarray]:
        """A world's fields as numpy arrays (what the run store keeps)."""
        return {f.name: np.asarray(getattr(world, f.name)) for f in dataclasses.fields(self.world_type)}

    def world_from_arrays(self, arrays: Mapping[str, Any] | None) -> Any:
        """The world of ``world_to_arrays`` (batched or not); other fields are refused."""
        if arrays is None:
            raise WorldagentError("this evaluation was stored without its world; rerun the campaign with worlds kept.")
        expected = sorted(f.name for f in dataclasses.fields(self.world_type))
        if sorted(arrays) != expected:
            raise WorldagentError(
                f"stored world has fields {sorted(arrays)}, not those of a {self.name} world ({expected}); pass the right environment."
            )
        return self.world_type(**{name: np.asarray(arrays[name]) for name in expected})

    def stack_worlds(self, worlds: list[Mapping[str, Any]]) -> Any:
        """One batched world (leading axis n) from n stored worlds (dicts of arrays)."""
        if not worlds:
            raise WorldagentError("no worlds to stack; pass at least one.")
        names = [f.name for f in dataclasses.fields(self.world_type)]
        return self.world_from_arrays({name: np.stack([np.asarray(w[name]) for w in worlds]) for name in names})


_REGISTRY: dict[str, EnvSpec] = {}
_loaded = False


def register(spec: EnvSpec, replace: bool = False) -> EnvSpec:
    """Add ``spec`` to the registry; a second spec of the same name is refused unless ``replace``."""
    if not isinstance(spec, EnvSpec):
        raise WorldagentError(f"register takes an EnvSpec, not a {type(spec).__name__}.")
    if spec.name in _REGISTRY and _REGISTRY[spec.name] is not spec and not replace:
        raise WorldagentError(f"an environment called {spec.name!r} is registered already; pick another name or pass replace=True.")
    _REGISTRY[spec.name] = spec
    return spec


def unregister(name: str) -> None:
    """Remove an environment (tests register toy environments and remove them again)."""
    _REGISTRY.pop(name, None)


def _load() -> None:
    """Import the built-in specs and the entry points of installed packages, once."""
    global _loaded
    if _loaded:
        return
    _loaded = True
    for module in BUILTIN:
        importlib.import_module(module)
    from importlib.metadata import entry_points

    for entry in entry_points(group=ENTRY_POINT_GROUP):
        try:
            found = entry.load()
            spec = found() if callable(found) and not isinstance(found, EnvSpec) else found
            if spec.name not in _REGISTRY:
                register(spec)
        except Exception as error:  # noqa: BLE001 - a broken plugin must not break the tool
            import warnings

            warnings.warn(f"worldagent: environment plugin {entry.name!r} failed to load ({error})", stacklevel=2)


def names() -> tuple[str, ...]:
    """The registered environments' names, in registration order."""
    _load()
    return tuple(_REGISTRY)


def get(name: str | EnvSpec) -> EnvSpec:
    """The spec called ``name`` (a spec is returned as is); unknown names list the known ones."""
    if isinstance(name, EnvSpec):
        return name
    _load()
    if name not in _REGISTRY:
        raise WorldagentError(f"unknown environment {name!r}; use one of: {', '.join(_REGISTRY)} (`worldagent envs` lists them).")
    return _REGISTRY[name]
