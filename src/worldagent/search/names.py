"""A stored campaign in words, from what the store recorded of it (``store.Campaign``), never from its name.

``cmaes-min-return-s0`` reads "CMA-ES minimising return, 420 evaluations, seed 0"; a failure-rate estimate,
an atlas, a `worldagent diff` and an evaluation of given worlds each say what they are. The explorer shows
these beside the ids; a campaign the store has no record of is shown by its id alone.
"""

from __future__ import annotations

from typing import Any

# what the store records as a campaign's optimiser, in words
OPTIMISER_WORDS = {
    "cmaes": "CMA-ES",
    "bo": "Bayesian optimisation",
    "cma-me": "CMA-ME",
    "mc": "Monte Carlo",
    "is": "importance sampling",
}


def describe_campaign(campaign: Any, name: str) -> str:
    """What campaign ``name`` is, in words, from its stored record (``RunStore.campaign(name)``).

    Args:
        campaign: the store's ``Campaign`` (optimiser, objective, maximize, budget, seed, config), or None.
        name: the campaign's id, what is said when there is no record.

    Returns:
        e.g. "CMA-ES minimising return, 420 evaluations, within |z| <= 5.44, seed 0",
        "Failure rate of crash_rate > 0.5 by importance sampling, 1,000 worlds, seed 0",
        "Diff of two agents on 1,000 random worlds G(z), seed 0".
    """
    if campaign is None:
        return name
    config = campaign.config if isinstance(campaign.config, dict) else {}
    return f"{campaign_head(campaign, config)}{bound_words(config)}, seed {campaign.seed}"


def bound_words(config: dict) -> str:
    """ ", within |z| <= 5.44" or ", beyond the prior": where a search was allowed to go (``campaign.PRIOR_KEY``);
    nothing for a campaign that records no bound (random search, or one from before bounds)."""
    if "prior_bound" not in config:
        return ""
    radius = config["prior_bound"]
    return ", beyond the prior" if radius is None else f", within |z| <= {float(radius):.3g}"


def campaign_head(campaign: Any, config: dict) -> str:
    """The description without its seed: what the campaign searched or scored, how, and how much."""
    metric, optimiser = campaign.objective, campaign.optimiser
    direction = "maximising" if campaign.maximize else "minimising"
    evaluations = f"{int(campaign.budget):,} evaluations"
    if config.get("event"):  # analysis.stored: a failure-rate estimate scores a margin to the event
        worlds = int(config.get("worlds") or campaign.budget)
        return f"Failure rate of {config['event']} by {OPTIMISER_WORDS.get(optimiser, optimiser)}, {worlds:,} worlds"
    if isinstance(config.get("diff"), dict):
        return diff_head(campaign, config, direction, evaluations)
    if "atlas" in config:
        return f"Atlas (CMA-ME) {direction} {metric}{over_descriptors(config)}, {evaluations}"
    if optimiser == "random":
        return f"Random worlds G(z) scored on {metric}, {int(campaign.budget):,} worlds"
    if optimiser == "given":
        worlds = config.get("worlds") if isinstance(config.get("worlds"), dict) else {}
        return f"Given worlds {worlds.get('tag', '')} scored on {metric}, {int(worlds.get('count', campaign.budget)):,} worlds".replace("  ", " ")
    return f"{OPTIMISER_WORDS.get(optimiser, optimiser)} {direction} {metric}, {evaluations}"


def diff_head(campaign: Any, config: dict, direction: str, evaluations: str) -> str:
    """A `worldagent diff` campaign (``differential``): both agents on a world set, or a search for where B does worse."""
    gap = f"{campaign.objective}(B) − {campaign.objective}(A)"
    if "atlas" in config:
        return f"Diff atlas (CMA-ME) {direction} {gap}{over_descriptors(config)}, {evaluations}"
    if campaign.optimiser == "random":
        return f"Diff of two agents on {int(campaign.budget):,} random worlds G(z)"
    if campaign.optimiser == "fixed":
        source = config.get("worlds") if isinstance(config.get("worlds"), dict) else {}
        where = f"the worlds of campaign {source['campaign']}" if source.get("campaign") else "given worlds"
        return f"Diff of two agents on {where}, {int(campaign.budget):,} worlds"
    return f"Diff search: {OPTIMISER_WORDS.get(campaign.optimiser, campaign.optimiser)} {direction} {gap}, {evaluations}"


def over_descriptors(config: dict) -> str:
    """`` over total_curvature × sharpest_corner``: an atlas's grid axes, or nothing when unrecorded."""
    grid = config["atlas"].get("grid", {}) if isinstance(config.get("atlas"), dict) else {}
    names = [str(d) for d in grid.get("descriptors", ())]
    return f" over {' × '.join(names)}" if names else ""
