"""Failure-probability estimates read back from a run store, with no agent and no generator.

``experiments.failure_rate`` keeps each estimate as one store campaign whose generations are
the estimator's calls of ``evaluate`` (``analysis.failure_rate``). The estimators are
deterministic given their seed and what ``evaluate`` returns, so running them again over the
stored generations gives the same estimate, interval and ESS: the report recomputes its
probability table that way instead of copying a phase's log.
"""

from __future__ import annotations

from functools import partial

from worldagent.analysis import failure_rate as fr
from worldagent.errors import WorldagentError


def failure_names(store) -> list[str]:
    """The store's failure-rate campaigns (``failure-mc-…``, ``failure-is-…``), in the order they were made."""
    return [c.name for c in store.campaigns() if c.optimiser in fr.METHODS and "event" in c.config]


def read_estimate(store, name: str) -> fr.Estimate:
    """Estimate campaign ``name`` again from its stored worlds (nothing is evaluated).

    Raises:
        WorldagentError: when ``name`` is no failure-rate campaign, or is unfinished (rerun
            ``worldagent failure-rate`` with the same settings to finish it).
    """
    from worldagent.influence.selection import parse_selection

    campaign = store.campaign(name)
    if campaign is None or name not in failure_names(store):
        known = ", ".join(failure_names(store)) or "none"
        raise WorldagentError(f"{name!r} is not a failure-rate campaign of {store.path}; estimates there: {known}.")
    config = campaign.config
    selection = parse_selection(config["event"], campaign.env)
    first = next(store.iter_evaluations(name), None)
    if first is None:
        raise WorldagentError(f"estimate {name!r} has no evaluated world yet; rerun `worldagent failure-rate` to finish it.")

    def unfinished(z, seeds):
        raise WorldagentError(f"estimate {name!r} is unfinished in {store.path}; rerun `worldagent failure-rate` with its settings to finish it.")

    evaluate = fr.StoredEvaluate(store, campaign, unfinished, partial(fr.score_worlds, selection))
    dim = len(first.latent)
    common = dict(seed=campaign.seed, batch=config["batch"], target_width=config.get("target_width"))
    if campaign.optimiser == "is":
        fields = fr.ImportanceConfig.__dataclass_fields__
        importance = fr.ImportanceConfig(**{k: v for k, v in config.items() if k in fields})
        return fr.importance_sampling(evaluate, dim, config["worlds"], config=importance, **common)
    return fr.monte_carlo(evaluate, dim, config["worlds"], **common)
