"""The paper's racing influencing experiment (§6.2.1, Figure 8a) with the paper's agent, evidence kept.

    python benchmarks/influence_racing.py                    # ACKTR, rays, 5 seeds x 10,000 episodes, 1,000 worlds x 8
    python benchmarks/influence_racing.py --algo ppo --seeds 0 1 --episodes 2000 --eval-worlds 100 --work runs/influence-racing-small
    # issue 26, item 1: the paper's regime (NAME: racing-regime.json's "chosen"), the paper's selection
    python benchmarks/influence_racing.py --regime NAME --selection paper
    # issue 26, item 2: our fully trained agent, its own failure, plus held-out failing worlds
    python benchmarks/influence_racing.py --regime ours --selection ours
    # the same, its default arm the curriculum benchmark's dr agents (that regime, G(z) and seeds 0-4)
    python benchmarks/influence_racing.py --regime ours --selection ours --generator runs/quick/racing/generator \\
        --default-agents runs/curriculum-racing/dr/s{0,1,2,3,4} --work runs/influence-racing-ours
    # issue 50 item 6 at the quick preset's scale: its agent (and its options), G(z) and selection, confirmed
    python benchmarks/influence_racing.py --algo ppo --given-agent runs/quick/racing/agent --generator runs/quick/racing/generator \
        --selection "crash_rate > 0" --episodes 10000 --candidates 500 --search-budget 0 --atlas-budget 105 --skip-census \
        --eval-worlds 1000 --seeds 0 1 2 --confirm 32 --work runs/influence-racing-quick --results benchmarks/results/influence-racing-confirmed.json
    # smoke (tiny budgets; not a measurement, write it elsewhere):
    python benchmarks/influence_racing.py --regime ours --selection ours --episodes 32 --eval-worlds 16 --seeds 0 1 \\
        --candidates 16 --atlas-budget 105 --search-budget 105 --heldout-search-budget 105 \\
        --generator runs/quick/racing/generator --work /tmp/influence-smoke --results /tmp/influence-smoke.json

The agent sees what the paper's does (§5.1.1: "its surrounding area, as well as its current
position and directional speed"): racing's ``rays`` observation, trained with the settings of
``--regime`` (``benchmarks/racing_regime.py``'s list; default ``ours``: those the racing spec
gives it, ``option_overrides``, that made it lap, ``docs/racing.md``), the same for the given
agent and both arms; ``--episodes`` scales the regime's budget (a 10,000-episode regime trains
``--episodes``). Steps, each cached under ``--work`` (a killed run resumes where it stopped;
another regime or budget than the default works under ``--work/regime-<name>-e<episodes>/``):

1. the generator G(z): ``--generator`` if it holds one, else the paper preset's dataset and VAE
   made under ``--work``;
2. the given agent, whose failures select the worlds: ``--algo`` trained ``--episodes`` on the
   procedural dataset pool (paper §5.3), or ``--given-agent``, one already trained in the regime
   (e.g. the default arm's seed 0, trained on G(z); its steps then live under ``given-<path>/``; both arms
   then train with the env options it was trained with, e.g. the quick preset's ``route`` observation);
3. the paper's selection, ``crash_rate > 0.5``: how many *distinct* tracks the given agent
   crashes on in more than half of its episodes, among ``--candidates`` random worlds and in a
   crash-maximising CMA-ME atlas of ``--atlas-budget`` worlds; and a census of every dataset
   track (``repeats`` episodes each; ``--skip-census``: not made): racing's repair maps every G(z) to its
   nearest dataset track, so the census bounds how many distinct tracks any search can select;
4. ``experiments.influence`` with ``--selection``: ``paper`` is the paper's ``crash_rate > 0.5``;
   ``ours`` the agent's own failure, ``lap_completed < 0.5``; ``auto`` (the default) the paper's
   when step 3 found at least ``MIN_DISTINCT`` tracks, else ``crash_rate > 0`` (every track it
   crashed on at all); any other text is a selection as written. Candidates are random worlds
   plus an atlas search (``--search-budget``) toward the selection, which collects distinct tracks;
   with ``--confirm N`` only the selected worlds that keep the property on N fresh episodes each
   are trained on (``influence.confirmation``; recorded: how many of the raw selection survived);
5. speed: every trained agent's mean steps per lap (episodes that lapped) on the evaluation worlds;
6. held out (``--heldout``; ``auto``: with ``--selection ours``): for each seed k, the worlds
   meeting the selection for seed k's *default* agent, among the evaluation worlds and in an
   atlas search of ``--heldout-search-budget`` worlds toward the selection, less any track of the
   influenced training worlds; seed k+1's (mod n) default and influenced agents are evaluated on
   them (8 episodes each, the same keys for both): worlds neither was selected or trained on
   (the default arm trains on G(z), where any track may come up);
7. the selected tracks replayed: every trained agent, 8 episodes on each distinct track of the
   influenced training worlds (the same keys for all): whether they are hard for agents other than
   the one that selected them, and whether the influenced agents learned them; and the same on
   ``--replay-repeats`` episodes of the confirmation key stream (not the keys that kept the worlds),
   influenced against default pooled over seeds and paired by world (``analysis.diff.pooled_difference``).

Records the run in ``benchmarks/results/influence-racing.json`` (``--results`` to choose) under
``runs["<regime>-e<episodes>-<selection>"]``, beside the other regimes' runs: the regime and every setting
that differs from the paper's, the given agent's own rates, per-seed values, means with 95%
intervals (Student t over seeds) and whether they overlap, the selection, its size and how many
distinct tracks it holds, steps per lap, the held-out evaluation, the agents that failed to
train (``failed_training``), the budgets, the machine and the paper's numbers.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import sys
import time
from pathlib import Path

import jax
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from curriculum import link_default_agents  # noqa: E402
from influence_harvest import comparison  # noqa: E402
from influence_pooled import pooled_influenced_vs_default  # noqa: E402
from machine import RESULTS, describe_machine  # noqa: E402
from racing_regime import OPTIONS, REPEATS, episode_summary, in_window, regimes  # noqa: E402
from worldagent import experiments  # noqa: E402
from worldagent.agents.algorithms import training_config  # noqa: E402
from worldagent.agents.distributions import world_distribution  # noqa: E402
from worldagent.agents.training import train  # noqa: E402
from worldagent.envs import registry  # noqa: E402
from worldagent.evaluation.backends import BACKENDS, make_backend  # noqa: E402
from worldagent.evaluation.local import evaluate  # noqa: E402
from worldagent.files import write_text  # noqa: E402
from worldagent.influence.cache import config_dict, load_influenced_worlds  # noqa: E402
from worldagent.influence.confirmation import DEFAULT_REPEATS, confirmation_line, trained_on_selected  # noqa: E402
from worldagent.influence.experiment import trained_policies  # noqa: E402
from worldagent.influence.statistics import episode_values, json_safe, mean_and_ci, summarise  # noqa: E402
from worldagent.influence.worlds import search_direction  # noqa: E402
from worldagent.search.atlas import distinct_count  # noqa: E402
from worldagent.store import RunStore, world_digest  # noqa: E402
from worldagent.worlds.dataset import WorldDataset, make_dataset  # noqa: E402
from worldagent.worlds.generator import build_generator, load_generator, save_generator  # noqa: E402
from worldagent.worlds.vae import VAEConfig, train_vae  # noqa: E402

SPEC = registry.get("racing")
PAPER = SPEC.presets["paper"]
PAPER_SELECTION = "crash_rate > 0.5"
FALLBACK_SELECTION = "crash_rate > 0"
OUR_SELECTION = "lap_completed < 0.5"  # issue 26, item 2: the agent's own failure (its training check's threshold)
SELECTIONS = {"paper": PAPER_SELECTION, "ours": OUR_SELECTION}  # --selection's names (and "auto")
# The paper's racing influence result (§6.2.1, Figure 8a) and its random worlds' rewards (§6.1), from the spec.
PAPER_NUMBERS = {
    "crashed": {label: SPEC.paper[f"influence.crashed.{label}"] for label in ("default", "influenced")},
    "reward_change_pct": SPEC.paper["influence.reward_change_pct"],
    "random": {"mean_normalised": SPEC.paper["random.mean_normalised"], "min": SPEC.paper["min.normalised"], "max": SPEC.paper["max.normalised"]},
}
MIN_DISTINCT = 50  # issue 13: the influenced distribution holds at least this many distinct tracks
SELECTED_SEED = 2000  # episode keys of step 7 (the selected tracks replayed)
HELDOUT_SEED = 1000  # seed of the held-out atlas and episode keys: HELDOUT_SEED + the source seed
EPISODE_METRICS = ("crashed", "lap_completed", "steps", "normalised_return", "return")


def generator_dir(work: Path, given: Path, progress: bool) -> Path:
    """``given`` if it holds a generator, else the paper preset's dataset and G(z) under ``work``."""
    if (given / "generator.json").is_file():
        return given
    data_path, gen_dir = work / "dataset.npz", work / "generator"
    if not data_path.exists():
        make_dataset(SPEC, PAPER["worlds"], 0, progress=progress).save(data_path)
    if not (gen_dir / "generator.json").exists():
        data = WorldDataset.load(data_path, env=SPEC.name)
        vae = train_vae(data, VAEConfig(epochs=PAPER["vae_epochs"]), progress=progress, checkpoint_dir=gen_dir)
        save_generator(gen_dir, vae, data_path, build_generator(vae, data))
    return gen_dir


def given_agent(work: Path, algo: str, config, progress: bool) -> Path:
    """The agent whose crashes select the worlds, trained on the procedural pool with ``config`` (resumed if killed)."""
    out = work / f"agent-{algo}"
    if not (out / "policy").exists():
        pool = world_distribution(SPEC, "generator", size=PAPER["worlds"], seed=0)
        train(SPEC, algo, config, pool, out, seed=0, options=OPTIONS, progress=progress, resume=True)
    return out


def distinct_failing(store: RunStore, campaigns: list[str], selection) -> dict:
    """Worlds of ``campaigns`` that meet ``selection``, and how many distinct tracks they are."""
    worlds = [e for name in campaigns for e in store.iter_evaluations(name, with_worlds=True)]
    mask = selection.mask(worlds) if worlds else np.zeros(0, bool)
    hits = [e.world for e, hit in zip(worlds, mask) if hit and e.world is not None]
    return {"evaluated": len(worlds), "meeting": int(mask.sum()), "distinct": distinct_count(hits)}


def paper_selection_reach(work: Path, setup, candidates: int, atlas_budget: int, progress: bool) -> dict:
    """Step 3: distinct ``crash_rate > 0.5`` tracks among random candidates and in a crash atlas;
    and the given agent's own rates on the random candidates (``racing_regime.episode_summary``)."""
    selection = experiments.failure_selection(PAPER_SELECTION, SPEC.name)
    with RunStore(work / "paper-selection") as store:
        found = experiments.random_evaluation(store, setup, "crashed", worlds=candidates, seed=0, progress=progress)
        random_name = experiments.campaign_names("crashed", 0)["random"]
        atlas = experiments.atlas(store, setup, "crash_rate", maximize=True, budget=atlas_budget, failure=PAPER_SELECTION, progress=progress)
        crash = np.array([e.score for e in store.evaluations(random_name)])
        own = episode_summary({m: episode_values(found, m) for m in EPISODE_METRICS})
        return {
            "selection": PAPER_SELECTION,
            "random": {**distinct_failing(store, [random_name], selection), "crash_rate_mean": round(float(crash.mean()), 4)},
            "atlas": {
                "budget": atlas_budget,
                "meeting": atlas["failing"],
                "distinct": atlas["distinct_failing"],
                "max_crash_rate": round(float(max(e.score for e in atlas["evaluations"])), 4),
                "coverage": round(float(atlas["coverage"]), 4),
            },
            "given_agent": {**own, "in_paper_window": in_window(own["crash_rate"], own["lap_rate"]), "worlds": len(found), "repeats": setup.repeats},
        }


def agent_options(agent_dir: Path) -> dict:
    """The env options a saved agent was trained with (its ``run.json``), or the regime's ``OPTIONS``."""
    record = agent_dir / "run.json"
    return json.loads(record.read_text()).get("options") or OPTIONS if record.is_file() else OPTIONS


def dataset_census(gen_dir: Path, setup, repeats: int, cache: Path) -> dict:
    """How many of the generator's dataset tracks (G(z)'s whole range after repair) meet each crash-rate threshold
    (kept in ``cache``: 10,000 tracks x 8 episodes is minutes of work)."""
    if cache.is_file():
        return json.loads(cache.read_text())
    data = load_generator(gen_dir)[2]
    crashed = evaluate(setup.env, setup.policy, data.worlds, repeats, jax.random.key(0), setup.params)["crashed"]
    rate = np.asarray(crashed, np.float64).mean(axis=1)
    census = {
        "tracks": len(rate),
        "repeats": repeats,
        "crash_rate_mean": round(float(rate.mean()), 4),
        "tracks_with_crash_rate_above": {str(t): int((rate > t).sum()) for t in (0.0, 0.125, 0.25, 0.375, 0.5)},
    }
    write_text(cache, json.dumps(census, indent=1))
    return census


def eval_campaign(name: str, result: dict) -> str:
    """The campaign of ``influence.compare_agents`` holding agent ``name``'s evaluation episodes."""
    return f"influence-eval-{name}-w{result['config']['eval_worlds']}-r{result['config']['repeats']}"


def steps_per_lap(influence_dir: Path, result: dict) -> dict:
    """{label: {seed: mean steps of the lapped evaluation episodes}}: lower is faster."""
    out: dict[str, dict[str, float]] = {}
    with RunStore(influence_dir) as store:
        for name in result["agents"]:
            found = store.evaluations(eval_campaign(name, result))
            steps, lapped = episode_values(found, "steps"), episode_values(found, "lap_completed") > 0.5
            label, seed = name.rsplit("-s", 1)
            out.setdefault(label, {})[seed] = round(float(steps[lapped].mean()), 2) if lapped.any() else float("nan")
    return out


def per_world(worlds) -> list[dict]:
    """A batched world as one dict of arrays per world (the run store's form)."""
    arrays = SPEC.world_to_arrays(worlds)
    return [{k: np.asarray(v[i]) for k, v in arrays.items()} for i in range(len(next(iter(arrays.values()))))]


def decoded(G, latents: list[np.ndarray], batch: int = 250) -> list[dict]:
    """The worlds G(z) of ``latents``, one dict of arrays each."""
    out = []
    for at in range(0, len(latents), batch):
        out += per_world(jax.tree_util.tree_map(np.asarray, G(np.stack(latents[at : at + batch]))))
    return out


def summary_over_seeds(per_seed: dict[str, dict[str, dict]], metrics) -> dict:
    """{metric: {label: mean_and_ci}} over the seeds whose value is finite (a seed that never lapped has no steps per lap)."""
    return {m: {label: mean_and_ci([row[m] for row in rows.values() if np.isfinite(row[m])]) for label, rows in per_seed.items()} for m in metrics}


def heldout_evaluation(influence_dir: Path, setup, result: dict, selection_text: str, search_budget: int, progress: bool) -> dict:
    """Step 6: seed k+1's (mod n) default and influenced agents on the worlds failing for seed k's default agent
    (``selection_text``), among the evaluation worlds and in an atlas toward it, less the influenced training tracks."""
    seeds = [int(s) for s in result["config"]["seeds"]]
    if len(seeds) < 2:
        return {"skipped": "held-out worlds come from another seed's default agent: pass two or more --seeds"}
    selection = experiments.failure_selection(selection_text, SPEC.name)
    metric = selection.resolve(SPEC.name).metrics[0]
    dirs = {name: influence_dir / "agents" / name / record["policy"] for name, record in result["agents"].items()}
    policies = trained_policies(dirs, SPEC, greedy=False)
    trained_on = {world_digest(w) for w in per_world(load_influenced_worlds(influence_dir, SPEC)[0])}
    failed = result["failed_training"]
    per_seed: dict[str, dict[str, dict]] = {"default": {}, "influenced": {}}
    sets = {}
    with RunStore(influence_dir) as store, RunStore(influence_dir / "heldout") as held:
        for i, source in enumerate(seeds):
            target, name = seeds[(i + 1) % len(seeds)], f"default-s{source}"
            found = store.evaluations(eval_campaign(name, result))
            worlds = decoded(setup.generator, [e.latent for e, hit in zip(found, selection.mask(found)) if hit]) if found else []
            from_eval = len(worlds)
            if search_budget > 0:
                atlas_name = f"heldout-atlas-{name}"
                experiments.atlas(
                    held,
                    dataclasses.replace(setup, policy=policies[name]),
                    metric,
                    maximize=search_direction(selection, np.zeros(0)),
                    budget=search_budget,
                    seed=HELDOUT_SEED + source,  # not the influence search's seed: other worlds than it tried
                    failure=selection_text,
                    name=atlas_name,
                    progress=progress,
                )
                searched = held.evaluations(atlas_name, with_worlds=True)
                worlds += [e.world for e, hit in zip(searched, selection.mask(searched)) if hit and e.world is not None]
            unique = {world_digest(w): w for w in worlds}
            kept = [w for key, w in unique.items() if key not in trained_on]
            sets[str(target)] = {
                "source_seed": source,
                "from_evaluation_worlds": from_eval,
                "from_search": len(worlds) - from_eval,
                "distinct": len(unique),
                "dropped_trained_on": len(unique) - len(kept),
                "worlds": len(kept),
                "source_failed_training": name in failed,
            }
            if not kept:
                continue
            batch, key = SPEC.stack_worlds(kept), jax.random.key(HELDOUT_SEED + source)
            for label in per_seed:
                metrics = SPEC.metrics.with_derived(
                    evaluate(setup.env, policies[f"{label}-s{target}"], batch, REPEATS, key, setup.params), setup.params
                )
                per_seed[label][str(target)] = episode_summary(metrics)
    metrics = ("crash_rate", "lap_rate", "normalised_return", "return", "steps_per_lap")
    summary = summary_over_seeds(per_seed, metrics)
    clean = [t for t, about in sets.items() if not about["source_failed_training"] and not {f"default-s{t}", f"influenced-s{t}"} & set(failed)]
    trained = {label: {t: row for t, row in rows.items() if t in clean} for label, rows in per_seed.items()}
    summary_trained = summary_over_seeds(trained, metrics)
    return {
        "selection": selection_text,
        "search_budget": search_budget,
        "repeats": REPEATS,
        "pairs": "seed k's default agent's failing worlds -> seed k+1's (mod n) agents",
        "sets": sets,
        "per_seed": per_seed,
        "summary": summary,
        "intervals": comparison(summary),
        "pooled_influenced_vs_default": pooled_influenced_vs_default(influence_dir),  # paired by world, pooled over seeds
        "without_failed_training": {"seeds": clean, "summary": summary_trained, "intervals": comparison(summary_trained)},
    }


def selected_world_rates(influence_dir: Path, setup, result: dict) -> dict:
    """Step 7: every trained agent on the influenced training worlds (one per distinct track, 8 episodes,
    one key for all): are the selected tracks hard for agents other than the one that selected them,
    and did the influenced agents learn to drive them?"""
    unique = {world_digest(w): w for w in per_world(load_influenced_worlds(influence_dir, SPEC)[0])}
    dirs = {name: influence_dir / "agents" / name / record["policy"] for name, record in result["agents"].items()}
    policies = trained_policies(dirs, SPEC, greedy=False)
    batch, key = SPEC.stack_worlds(list(unique.values())), jax.random.key(SELECTED_SEED)
    per_seed: dict[str, dict[str, dict]] = {}
    for name, policy in policies.items():
        label, seed = name.rsplit("-s", 1)
        metrics = SPEC.metrics.with_derived(evaluate(setup.env, policy, batch, REPEATS, key, setup.params), setup.params)
        per_seed.setdefault(label, {})[seed] = episode_summary(metrics)
    return {
        "tracks": len(unique),
        "repeats": REPEATS,
        "per_seed": per_seed,
        "summary": summary_over_seeds(per_seed, ("crash_rate", "lap_rate", "normalised_return")),
    }


def slug(text: str) -> str:
    """A selection's text as a file-name part."""
    return re.sub(r"[^a-z0-9.]+", "-", text.lower()).strip("-")


def record_run(path: Path, key: str, payload: dict) -> Path:
    """Write ``payload`` as ``runs[key]`` of the results file, keeping the other runs (regimes, selections) it holds."""
    runs = json.loads(path.read_text()).get("runs", {}) if path.is_file() else {}
    runs[key] = payload
    document = {"benchmark": "influence-racing", "paper": PAPER_NUMBERS, "runs": dict(sorted(runs.items()))}
    return write_text(path, json.dumps(json_safe(document), indent=2, default=float) + "\n")


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algo", choices=SPEC.algorithms, default="acktr", help="the paper's: acktr")
    parser.add_argument(
        "--regime", choices=list(regimes()), default="ours", help="the training regime (benchmarks/racing_regime.py); ours: the spec's"
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument(
        "--episodes", type=int, default=None, help="scale the regime's budget: a 10,000-episode regime (the paper's) trains this many"
    )
    parser.add_argument("--candidates", type=int, default=PAPER["influence_candidates"])
    parser.add_argument("--atlas-budget", type=int, default=2100, help="worlds of the crash-maximising atlas of step 3")
    parser.add_argument("--search-budget", type=int, default=2100, help="worlds of the influence candidate search (CMA-ME atlas)")
    parser.add_argument(
        "--selection",
        default="auto",
        help=f"paper: {PAPER_SELECTION!r}; ours: {OUR_SELECTION!r}; auto: {PAPER_SELECTION!r} if it holds {MIN_DISTINCT} distinct tracks, "
        f"else {FALLBACK_SELECTION!r}; or a selection's text",
    )
    parser.add_argument("--heldout", choices=("auto", "on", "off"), default="auto", help="step 6 (auto: with --selection ours)")
    parser.add_argument("--heldout-search-budget", type=int, default=420, help="worlds of each default agent's atlas toward the selection (step 6)")
    parser.add_argument("--eval-worlds", type=int, default=1000)
    parser.add_argument("--generator", type=Path, default=Path("runs/generators/racing"))
    parser.add_argument("--work", type=Path, default=Path("runs/influence-racing"))
    parser.add_argument(
        "--results", type=Path, default=None, help="the result file (default under benchmarks/results/, named by regime and selection)"
    )
    parser.add_argument(
        "--default-agents",
        nargs="+",
        default=None,
        metavar="DIR",
        help="agents already trained in this regime on --generator's G(z), one per --seeds in order (e.g. the curriculum "
        "benchmark's dr arm): the default arm links them instead of training them again",
    )
    parser.add_argument(
        "--given-agent",
        type=Path,
        default=None,
        metavar="DIR",
        help="an agent already trained in this regime whose failures select the worlds (default: trained here on the procedural pool)",
    )
    parser.add_argument("--runs-per-program", type=int, default=None, help="agents trained as one program at most (default: from the device)")
    parser.add_argument(
        "--backend", choices=BACKENDS, default="local", help="ray: each program of agents trains on a worker of a local Ray cluster, side by side"
    )
    parser.add_argument(
        "--confirm", type=int, default=DEFAULT_REPEATS, help="fresh episodes each selected world is replayed on (0: the raw selection)"
    )
    parser.add_argument(
        "--replay-repeats", type=int, default=16, help="fresh episodes of every trained agent on each influenced world (step 7, pooled; 0: skipped)"
    )
    parser.add_argument("--skip-census", action="store_true", help="skip step 3's census of every dataset track (10,000 x 8 episodes)")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    progress, started = not args.quiet, time.perf_counter()
    if args.confirm < 0 or args.replay_repeats < 0:
        parser.error("--confirm and --replay-repeats take 0 or more episodes")
    regime = regimes()[args.regime]
    if args.algo != "acktr" and regime.overrides:
        parser.error(f"--regime {regime.name} sets ACKTR settings; use --algo acktr or --regime ours")
    if args.episodes is not None and args.episodes < 1:
        parser.error("--episodes must be at least 1")
    if args.default_agents and len(args.default_agents) != len(args.seeds):
        parser.error(f"--default-agents: give one agent per seed ({len(args.seeds)}), in --seeds' order")
    episodes = regime.budget(args.episodes)
    options = agent_options(args.given_agent) if args.given_agent is not None else OPTIONS
    config = regime.config(args.episodes, args.algo)
    if options != OPTIONS:  # the given agent's observation: both arms train with what it saw
        config = training_config(SPEC, args.algo, episodes, options=options, **dict(regime.overrides))
    default_run = regime.name == "ours" and args.episodes is None
    base = args.work if default_run else args.work / f"regime-{regime.name}-e{episodes}"
    base.mkdir(parents=True, exist_ok=True)
    gen_dir = generator_dir(args.work, args.generator, progress)
    if args.given_agent is not None:
        if not (args.given_agent / "policy").is_dir():
            parser.error(f"--given-agent {args.given_agent}: not a trained agent (no policy/); finish training it first")
        agent_dir, base = args.given_agent, base / f"given-{slug(str(args.given_agent))}"
        base.mkdir(parents=True, exist_ok=True)
    else:
        agent_dir = given_agent(base, args.algo, config, progress)
    setup = experiments.setup(SPEC, str(agent_dir), gen_dir, options=options, backend=make_backend(args.backend))
    reach = paper_selection_reach(base, setup, args.candidates, args.atlas_budget, progress)
    reach["dataset_census"] = None if args.skip_census else dataset_census(gen_dir, setup, setup.repeats, base / "dataset-census.json")
    enough = reach["random"]["distinct"] + reach["atlas"]["distinct"] >= MIN_DISTINCT  # an upper bound: the two may share tracks
    if args.selection == "auto":
        selection = PAPER_SELECTION if enough else FALLBACK_SELECTION
    else:
        selection = SELECTIONS.get(args.selection, args.selection)
    tag = "" if args.selection == "auto" else "-" + (args.selection if args.selection in SELECTIONS else slug(selection))
    tag += f"-confirm{args.confirm}" if args.confirm else ""  # another training distribution: its own directory and record
    influence_dir = base / f"influence-{args.algo}{tag}"
    if args.default_agents:
        link_default_agents(influence_dir, args.default_agents, args.seeds, source=f"linked from {args.default_agents[0]} and on")
    result = experiments.influence(
        influence_dir,
        setup,
        selection,
        algo=args.algo,
        episodes=episodes,
        seeds=tuple(args.seeds),
        candidates=args.candidates,
        search_budget=args.search_budget,
        search="atlas",
        eval_worlds=args.eval_worlds,
        runs_per_program=args.runs_per_program,
        config=config,
        progress=progress,
        confirm=args.confirm,
    )
    with RunStore(influence_dir) as store:
        selected = distinct_failing(store, result["worlds"]["campaigns"], experiments.failure_selection(selection, SPEC.name))
    speed = steps_per_lap(influence_dir, result)
    lapped = {label: [v for v in by_seed.values() if np.isfinite(v)] for label, by_seed in speed.items()}  # a parked seed never laps
    summary = {**result["summary"], "steps_per_lap": {label: mean_and_ci(values) for label, values in lapped.items()}}
    trained = {  # the same, without the agents the training check flagged (they weigh on the means above)
        label: {seed: row for seed, row in runs.items() if f"{label}-s{seed}" not in result["failed_training"]}
        for label, runs in result["per_seed"].items()
    }
    summary_trained = summarise(trained, list(result["summary"]))
    trained_seeds = [seed for seed in args.seeds if not {f"default-s{seed}", f"influenced-s{seed}"} & set(result["failed_training"])]
    heldout = args.heldout == "on" or (args.heldout == "auto" and selection == OUR_SELECTION)
    held = heldout_evaluation(influence_dir, setup, result, selection, args.heldout_search_budget, progress) if heldout else None
    replayed = selected_world_rates(influence_dir, setup, result)
    events = {"failure": experiments.failure_selection(SPEC.failure, SPEC.name).resolve(SPEC.name)}
    events["selection"] = experiments.failure_selection(selection, SPEC.name).resolve(SPEC.name)
    fresh = trained_on_selected(influence_dir, setup, result, events, repeats=args.replay_repeats, progress=progress) if args.replay_repeats else None
    given_why = SPEC.training_check({"lap_completed": reach["given_agent"]["lap_rate"]})
    failed_training = {**({"given-s0": given_why} if given_why else {}), **result["failed_training"]}
    reward = summary["return"]
    figures = {
        "command": "python benchmarks/influence_racing.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "algo": args.algo,
        "options": options,
        "regime": regime.record(args.episodes, args.algo),
        "settings": SPEC.option_overrides(args.algo, SPEC.check_options(options)),
        "training_config": config_dict(config),
        "budgets": {
            "episodes": episodes,
            "seeds": args.seeds,
            "candidates": args.candidates,
            "atlas_budget": args.atlas_budget,
            "search_budget": args.search_budget,
            "eval_worlds": args.eval_worlds,
            "repeats": setup.repeats,
            "heldout_search_budget": args.heldout_search_budget if heldout else None,
            "confirm": args.confirm,
            "replay_repeats": args.replay_repeats,
            "census": not args.skip_census,
        },
        "given_agent": {
            **reach["given_agent"],
            "dir": str(agent_dir),
            "trained": "here, on the procedural pool" if args.given_agent is None else "given",
        },
        "paper_selection_reach": reach,
        "selection": {
            **result["selection"],
            "chosen_by": args.selection,
            "distinct_selected_tracks": selected["distinct"],
            "selected_worlds": selected["meeting"],
            "meets_min_distinct": selected["distinct"] >= MIN_DISTINCT,
            "min_distinct": MIN_DISTINCT,
        },
        "worlds": result["worlds"],
        "confirmation": result["worlds"].get("confirmation"),  # how many of the raw selection kept the property on fresh episodes
        "selected_worlds_fresh": fresh,  # every trained agent on the influenced worlds, fresh keys, paired and pooled
        "per_seed": {**result["per_seed"], "steps_per_lap": speed},
        "summary": summary,
        "intervals": comparison(summary),
        "pooled_influenced_vs_default": pooled_influenced_vs_default(influence_dir),  # paired by world, pooled over seeds
        "without_failed_training": {
            "seeds": trained_seeds,
            "summary": summary_trained,
            "intervals": comparison(summary_trained),
            # the same pairing, leaving out every seed where either arm failed to train (both arms alike)
            "pooled_influenced_vs_default": pooled_influenced_vs_default(influence_dir, seeds=trained_seeds) if trained_seeds != args.seeds else None,
        },
        "reward_change_pct": round(100 * (reward["influenced"]["mean"] / reward["default"]["mean"] - 1), 2),
        "heldout": held,
        "selected_worlds_replayed": replayed,
        "failed_training": failed_training,
        "generator": str(gen_dir),
        "default_agents": args.default_agents or "trained here",
        "wall_seconds": round(time.perf_counter() - started, 1),
        "influence_wall_seconds": result["wall_seconds"],  # this process's: a rerun of cached steps times ~0
        "training_seconds": {name: record["wall_seconds"] for name, record in result["agents"].items()},  # each agent's own record
        "work": str(base),
    }
    machine = describe_machine()
    payload = {"when": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "machine": machine, **figures}
    path = record_run(args.results or RESULTS / "influence-racing.json", f"{regime.name}-e{episodes}{tag or '-auto'}", payload)
    own = reach["given_agent"]
    lines = [
        f"regime {regime.name} ({episodes} episodes): given agent crash {own['crash_rate']:.4f}, lap {own['lap_rate']:.4f}"
        f"{' (in the paper window)' if own['in_paper_window'] else ''}",
        f"paper selection: {reach['random']['distinct']} distinct of {args.candidates} random, {reach['atlas']['distinct']} in a {args.atlas_budget}-world atlas",
        f"{selected['distinct']} distinct tracks selected ({selection}); {machine['cores']} cores",
    ]
    for metric, by_label in summary.items():
        d, i = by_label["default"], by_label["influenced"]
        lines.append(
            f"{metric}: {d['mean']:.4f} ± {d['ci95']:.4f} -> {i['mean']:.4f} ± {i['ci95']:.4f} (overlap: {figures['intervals'][metric]['overlap']})"
        )
    if held and "summary" in held:
        for metric in ("crash_rate", "lap_rate"):
            d, i = held["summary"][metric]["default"], held["summary"][metric]["influenced"]
            lines.append(f"held out {metric}: {d['mean']:.4f} ± {d['ci95']:.4f} -> {i['mean']:.4f} ± {i['ci95']:.4f} ({d['seeds']} seeds)")
    for metric in ("crash_rate", "lap_rate"):
        d, i = replayed["summary"][metric]["default"], replayed["summary"][metric]["influenced"]
        lines.append(f"selected tracks replayed, {metric}: {d['mean']:.4f} ± {d['ci95']:.4f} -> {i['mean']:.4f} ± {i['ci95']:.4f}")
    if figures["confirmation"]:
        lines.append(confirmation_line(figures["confirmation"]))
    for key, row in (fresh or {}).get("pooled", {}).items():
        lines.append(
            f"selected worlds, fresh keys, {key}: default {row['base']:.4f}, influenced {row['arm']:.4f}, "
            f"{row['difference']:+.4f} [{row['low']:+.4f}, {row['high']:+.4f}]"
        )
    pooled = figures["pooled_influenced_vs_default"]["p_failure"]
    lines.append(
        f"{args.eval_worlds} fresh worlds, p_failure: default {pooled['base']:.4f}, influenced {pooled['arm']:.4f}, "
        f"{pooled['difference']:+.4f} [{pooled['low']:+.4f}, {pooled['high']:+.4f}]"
    )
    if failed_training:
        lines.append("failed training: " + ", ".join(failed_training))
    print("\n".join(lines) + f"\nrecorded in {path}")
    return figures


if __name__ == "__main__":
    main()
