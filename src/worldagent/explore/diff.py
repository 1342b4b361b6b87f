"""The explorer's Diff view: a ``worldagent diff`` campaign's regressed worlds, to play A and B side by side.

A diff campaign (``differential``) records the two agents it compared (``config["diff"]``: kind,
path, file hash) and stores, per episode, B's metrics under their names and A's under ``A.<name>``.
The agents of every diff campaign in a run's store join the explorer's fixed list of agents as
``diff/A`` and ``diff/B`` (``diff2/A`` ... for another pair), when ``load_agent`` can read them
again (an agent built in Python cannot be). The view ranks the campaign's regressed worlds (B
fails, A passes) by prior likelihood, each with its nearest stored world of that campaign where
B passes; a click opens one in the World view with A and B as its two agents, played with the
very episode keys the diff scored it with (each row's ``replay``: the seed and episode count the
World view's play takes), so the World view shows the episodes the table counts.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from worldagent.analysis.diff import regressed_ranking
from worldagent.analysis.paired import failure_masks
from worldagent.errors import WorldagentError
from worldagent.events import parse_selection
from worldagent.search.campaign import stored_seed

LOADABLE = ("worldagent", "scripted", "onnx", "callable", "sb3")  # agent kinds ``load_agent`` reads from their recorded path


def diff_campaigns(run: Any, env: str) -> dict[str, dict]:
    """{campaign: {"a": record, "b": record}} of the diff campaigns in ``env``'s store, in order."""
    if not run.has_store(env):
        return {}
    with run.store(env) as store:
        return {c.name: c.config["diff"] for c in store.campaigns() if isinstance(c.config.get("diff"), dict)}


def pair_labels(campaigns: dict[str, dict]) -> dict[str, tuple[str, str]]:
    """{campaign: (label of A, label of B)}: ``diff/A``, ``diff/B`` for the first distinct pair, ``diff2/...`` on."""
    pairs: list[tuple] = []
    labels = {}
    for name, records in campaigns.items():
        key = tuple((records[s].get("kind"), records[s].get("path")) for s in ("a", "b"))
        if key not in pairs:
            pairs.append(key)
        prefix = "diff" if pairs.index(key) == 0 else f"diff{pairs.index(key) + 1}"
        labels[name] = (f"{prefix}/A", f"{prefix}/B")
    return labels


def diff_agents(campaigns: dict[str, dict]) -> dict[str, str]:
    """{label: what ``load_agent`` reads} of every loadable agent of the diff campaigns."""
    found = {}
    for name, (label_a, label_b) in pair_labels(campaigns).items():
        for label, record in ((label_a, campaigns[name]["a"]), (label_b, campaigns[name]["b"])):
            if record.get("kind") in LOADABLE and record.get("path"):
                found[label] = str(record["path"]).removeprefix("scripted/")
    return found


def agent_text(record: dict) -> str:
    """What a recorded agent is, in words: ``scripted homing``, ``worldagent runs/quick/racing/agent``."""
    return " ".join(str(record[key]) for key in ("kind", "path") if record.get(key)) or "an agent of unknown kind"


def replay(evaluation: Any, campaign: Any) -> dict:
    """{"seed", "episodes"}: what the World view's play takes to replay a stored world's own episodes
    (its keys are ``split(key(seed), episodes)``, as the campaign played it)."""
    return {"seed": stored_seed(campaign, evaluation.generation, evaluation.slot), "episodes": len(evaluation.episodes)}


def stored_campaign(run: Any, env: str, campaign: str) -> Any:
    """Campaign ``campaign`` of ``env``'s store (``store.Campaign``: its seed and episode stream)."""
    with run.store(env) as store:
        return store.campaign(campaign)


def diff_view(session: Any, campaign: str | None, event: str | None, limit: int) -> dict:
    """The regressed worlds of diff campaign ``campaign`` (default: the first) under ``event`` (default: the env's failure).

    Returns:
        {"campaign", "campaigns", "campaign_words" (``EnvSession.campaign_words``: one written since the page loaded too), "agents": [label A, label B] (those loadable), "pair": {"A", "B"} (what each
        agent is, ``agent_text``), "event", "worlds",
        "regressed", "improved", "rows": [{"index", "log_prior", "a", "b" ({metric: mean}),
        "nearest_passing" (index or None), "distance", "replay", "nearest_replay" (``replay``'s
        {"seed", "episodes"} of the world and of its nearest passing one, or None)}]}.
    """
    campaigns = diff_campaigns(session.run, session.env)
    if not campaigns:
        raise WorldagentError(f"the {session.env} store holds no diff campaign; run `worldagent diff` with --out into this run.")
    campaign = campaign or next(iter(campaigns))
    if campaign not in campaigns:
        raise WorldagentError(f"no diff campaign {campaign!r}; diff campaigns of {session.env}: {', '.join(campaigns)}.")
    indices = [i for i, e in enumerate(session.evaluations) if e.campaign == campaign]
    if not indices:
        raise WorldagentError(f"diff campaign {campaign!r} has no worlds with latents to show (a dataset's worlds have none).")
    evaluations = [session.evaluations[i] for i in indices]
    text = event or session.spec.failure
    if not text:
        raise WorldagentError(f"{session.env} names no failure event; pass one, e.g. event={session.spec.metrics.main} < 0.")
    selection = parse_selection(text, session.env)
    fail_a, fail_b, a, b = failure_masks(evaluations, session.spec, selection)
    latents = session.latents[indices]
    shown = [m for m in dict.fromkeys((session.spec.metrics.main, *selection.metrics)) if m in a]
    seed = stored_campaign(session.run, session.env, campaign)
    rows = []
    for row in regressed_ranking(fail_a, fail_b, latents, latents)[:limit]:
        k, near = row["world"], row["nearest_passing"]
        rows.append(
            {
                "index": indices[k],
                "log_prior": row["log_prior"],
                "a": {m: float(np.mean(a[m][k])) for m in shown},
                "b": {m: float(np.mean(b[m][k])) for m in shown},
                "nearest_passing": None if near is None else indices[near],
                "distance": row["distance"],
                "replay": replay(evaluations[k], seed),
                "nearest_replay": None if near is None else replay(evaluations[near], seed),
            }
        )
    loadable = diff_agents(campaigns)
    return {
        "campaign": campaign,
        "campaigns": list(campaigns),
        "campaign_words": session.campaign_words(),
        "agents": [label for label in pair_labels(campaigns)[campaign] if label in loadable],
        "pair": {side.upper(): agent_text(campaigns[campaign][side]) for side in ("a", "b")},
        "event": selection.describe(),
        "worlds": len(evaluations),
        "regressed": int(np.sum(fail_b & ~fail_a)),
        "improved": int(np.sum(fail_a & ~fail_b)),
        "rows": rows,
    }
