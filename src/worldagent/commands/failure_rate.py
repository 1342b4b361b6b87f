"""``worldagent failure-rate ENV --event "crash_rate > 0.5"``: how likely a failure is under the world distribution."""

from __future__ import annotations

from pathlib import Path

import typer

from worldagent.analysis.failure_rate import ImportanceConfig
from worldagent.analysis.pooled import DEFAULT_POOL, MAX_POOL
from worldagent.commands.console import console, friendly_errors
from worldagent.commands.options import (
    AGENT_HELP,
    GENERATOR_HELP,
    backend_flag,
    check_counts,
    check_run_dir,
    check_seed,
    command_setup,
    env_argument,
    option_flag,
    ray_address_flag,
    stochastic_flag,
)

EVENT_HELP = (
    "The event: METRIC OP NUMBER joined by 'and', on per-world means over the episodes, "
    "e.g. 'crash_rate > 0.5' or 'return < 200' (the event language, worldagent.events)."
)


def estimate_line(estimate) -> str:
    """One line: the estimate, its interval, the worlds and episodes spent (and for IS the search's share and the ESS)."""
    name = {"mc": "Monte Carlo", "is": "importance sampling"}[estimate.method]
    name = "importance sampling fell back to Monte Carlo" if estimate.fallback else name
    line = (
        f"{name}: P = {estimate.estimate:.3g}, {estimate.confidence:.0%} interval [{estimate.low:.3g}, {estimate.high:.3g}]; "
        f"{estimate.hits} hits in {estimate.worlds} worlds, {estimate.episodes} episodes"
    )
    if estimate.method == "is":
        line += f" ({estimate.search_worlds} worlds learning the proposal); ESS {estimate.ess:.0f}, of the hits {estimate.event_ess:.0f}"
    return line


def cost_lines(estimate) -> list[str]:
    """What the estimate cost in wall time and, for a pooled proposal, what its plan predicted; a cap's note."""
    lines = [f"  {estimate.seconds:.1f} s wall time"]
    plan = estimate.plan
    if plan:
        pool = f"a pool of {plan['pool']:,} worlds" + (f" ({plan['describe_total']:.0f} s to describe)" if plan["describe_total"] else "")
        lines[0] += (
            f"; the plan (after the pilot, or the learned proposal's rounds) predicted {plan['gain_episodes']:.2g}x fewer episodes than"
            f" Monte Carlo and {plan['gain_seconds']:.2g}x less time,"
            f" with {pool}"
        )
    if estimate.fallback:
        lines.append(f"  fell back: {estimate.fallback}")
    if estimate.note:
        lines.append(f"  WARNING: {estimate.note}")
    return lines


CONFIRM_HELP = (
    "Fresh episodes on which each listed hit (a world in the event on its own episodes) is replayed, from keys no estimate "
    "draws (default 64; 0 skips): found beside confirmed, and how many still fail. P itself is not confirmed: it is an "
    "unbiased estimate over the prior (every world drawn counts, in the event or not), not a selection."
)


def hit_lines(hits: dict, shown: int = 5) -> list[str]:
    """How many of an estimate's hits survive confirmation (``analysis.stored.confirm_hits``), and the first ``shown``
    hits found beside confirmed."""
    from worldagent.analysis.confirm import Interval

    if hits is None:
        return ["  hits not confirmed (--confirm 0): each listed hit failed on its own few episodes, a figure biased by the selection"]
    if not hits["hits"]:
        return ["  no hit to confirm"]
    repeats = hits["confirmation_episodes"] // max(hits["distinct_worlds"], 1)
    of = f"the first {hits['checked']} in the order drawn" if hits["checked"] < hits["distinct_hits"] else f"all {hits['checked']}"
    lines = [
        f"  hits: {hits['hits']} worlds in the event ({hits['distinct_hits']} distinct); {of} confirmed on {repeats} fresh episodes each: "
        f"{hits['confirmed_failing']} of {hits['checked']} still fail ({hits['event']}, the confirmed interval beyond the threshold)"
    ]
    for row in hits["worlds"][:shown]:
        parts = []
        for metric in row["found"]:
            found, fresh = Interval(**rename(row["found"][metric])), Interval(**rename(row["confirmed"][metric]))
            parts.append(
                f"{metric} found {found.mean:.4g} (the selection's, {found.n} episodes); confirmed {fresh.text()} ({fresh.n} fresh episodes)"
            )
        verdict = "still fails" if row["confirmed_failing"] else "not confirmed"
        lines.append(f"    {row['campaign']} generation {row['generation']} slot {row['slot']}: {'; '.join(parts)} - {verdict}")
    if len(hits["worlds"]) > shown:
        lines.append(f"    ({shown} of {len(hits['worlds'])} shown; every confirmed hit is in failure-rate.json)")
    return lines


def rename(row: dict) -> dict:
    """``Interval.as_dict``'s keys back to ``Interval``'s fields."""
    return {"mean": row["mean"], "low": row["low"], "high": row["high"], "n": row["episodes"]}


def register(app: typer.Typer) -> None:
    """Add ``worldagent failure-rate``."""

    @app.command("failure-rate")
    @friendly_errors
    def failure_rate(
        env: str = env_argument(),
        agent: str = typer.Option(..., "--agent", help=AGENT_HELP),
        generator: Path = typer.Option(..., "--generator", help=GENERATOR_HELP),
        event: str = typer.Option(..., "--event", help=EVENT_HELP),
        method: str = typer.Option("both", "--method", help="mc (Monte Carlo, exact binomial interval), is (importance sampling) or both."),
        worlds: int = typer.Option(10_000, "--worlds", help="Monte Carlo's worlds; importance sampling's worlds after its search."),
        width: float = typer.Option(None, "--width", help="Stop sampling once the 95% interval is within ±WIDTH of the estimate (0.5: ±50%)."),
        proposal: str = typer.Option(
            ImportanceConfig.proposal,
            "--proposal",
            help="Importance sampling's proposal: surrogate (a model of the worlds' descriptors), learned (that model refitted over "
            "rounds toward the agent's near-misses) or search (cross-entropy over latents).",
        ),
        pool: int = typer.Option(
            None, "--pool", help="Surrogate: prior worlds decoded and described (no episode) to draw from (default: what --pool-seconds buys)."
        ),
        pool_seconds: float = typer.Option(
            ImportanceConfig.pool_seconds,
            "--pool-seconds",
            help=f"Surrogate: time budget for describing the pool when --pool is not given (timed on a sample; at most {DEFAULT_POOL:,} worlds).",
        ),
        pilot: int = typer.Option(
            ImportanceConfig.pilot, "--pilot", help="Surrogate, learned: pool worlds evaluated to fit the model (learned: and per round)."
        ),
        round_worlds: int = typer.Option(500, "--round-worlds", help="Search: worlds per round of the search for the proposal."),
        rounds: int = typer.Option(10, "--rounds", help="Search: rounds of the search at most."),
        components: int = typer.Option(8, "--components", help="Search: shifted priors in the proposal at most (1: one mean shift)."),
        repeats: int = typer.Option(8, "--repeats", help="Episodes per world (the paper: 8)."),
        seed: int = typer.Option(0, "--seed", help="Seed of the latents and episodes."),
        out: Path = typer.Option(Path("runs/failure-rate"), "--out", help="Run directory (store.sqlite); a rerun resumes."),
        option: list[str] = option_flag(),
        greedy: bool = typer.Option(False, "--greedy", help="Trained actor-critics act by argmax instead of sampling."),
        stochastic: bool = stochastic_flag(),
        backend_name: str = backend_flag(),
        ray_address: str = ray_address_flag(),
        confirm: int = typer.Option(None, "--confirm", help=CONFIRM_HELP),
        hits: int = typer.Option(20, "--hits", help="Distinct hit worlds of each estimate listed and confirmed, in the order drawn."),
        quiet: bool = typer.Option(False, "--quiet", help="No progress bar."),
    ) -> None:
        """The probability of an event (a failure) for worlds z ~ N(0, I), with a 95% interval and the episodes spent; the
        worlds it hit confirmed on fresh episodes (P is unbiased and stays as estimated; the listed hits are a selection)."""
        import json

        from worldagent import experiments
        from worldagent.analysis.failure_rate import check_budget, methods
        from worldagent.analysis.stored import campaign_name, confirm_hits
        from worldagent.errors import WorldagentError
        from worldagent.events import parse_selection
        from worldagent.files import write_text
        from worldagent.store import RunStore

        if confirm is not None and confirm < 0:
            raise WorldagentError(f"--confirm {confirm}; pass fresh episodes per listed hit (64 by default), or 0 to skip.")
        if hits < 0:
            raise WorldagentError(f"--hits {hits}; pass how many hit worlds to list and confirm (0: none).")

        counts = dict(worlds=worlds, repeats=repeats, round_worlds=round_worlds, rounds=rounds, components=components, pilot=pilot)
        check_counts({"pool": MAX_POOL, "pilot": MAX_POOL}, **counts, **({} if pool is None else {"pool": pool}))
        check_seed(seed)
        importance = ImportanceConfig(
            round_worlds=round_worlds, max_rounds=rounds, components=components, proposal=proposal, pool=pool, pilot=pilot, pool_seconds=pool_seconds
        )
        methods(method)
        check_budget(worlds, width, importance)
        parse_selection(event, env)  # a bad event fails before the agent and generator load
        check_run_dir(out)
        setup = command_setup(
            env, agent, generator, option, greedy=greedy, stochastic=stochastic, repeats=repeats, backend_name=backend_name, ray_address=ray_address
        )
        with RunStore(out) as store:
            say = lambda line: console.print(line, markup=False, highlight=False)  # noqa: E731
            found = experiments.failure_rate(
                store, setup, event, method=method, worlds=worlds, importance=importance, target_width=width, seed=seed, progress=not quiet, say=say
            )
            selection = parse_selection(event, env)
            confirmed = {
                m: confirm_hits(
                    store, setup, selection, campaign_name(m, selection.text, seed), seed=seed, repeats=confirm, limit=hits, progress=not quiet
                )
                for m in found
            }
        for m, estimate in found.items():
            for line in (estimate_line(estimate), *cost_lines(estimate), *hit_lines(confirmed[m])):
                console.print(line, markup=False, highlight=False)
        written = {m: {"estimate": estimate.as_dict(), "hits": confirmed[m]} for m, estimate in found.items()}
        write_text(out / "failure-rate.json", json.dumps({"event": event, "seed": seed, **written}, indent=1, default=float) + "\n")
        console.print(f"-> {out / 'store.sqlite'}, {out / 'failure-rate.json'}", markup=False, highlight=False)
