"""What makes two agents the same agent: their content, not where their files are now (DESIGN.md "Identity").

Every command that resumes a campaign, a confirmation or a paired diff compares agents by
``agent_identity`` of their records (``agents.policy.agent_record``).
"""

from __future__ import annotations


def agent_identity(record: dict) -> list:
    """What makes two agent records (``agents.policy.agent_record``) the same agent (DESIGN.md "Identity"): the
    kind and the hash of its files, not where they are now; a callable's function name beside its module's
    hash (two functions of one module are two agents); agents without files by their name."""
    kind, path, sha256 = record.get("kind"), record.get("path") or "", record.get("sha256")
    if kind == "callable":
        return [kind, path.partition(":")[2], sha256 or path]
    if kind == "python":  # built in Python: its name and its parameters' hash
        return [kind, path, sha256]
    return [kind, sha256 or path]


def resumable_parts(have: dict, wanted: dict) -> tuple[dict, dict]:
    """The parts of two campaign configs that must agree to resume: the agent by its identity
    (``agent_identity``: content, not where its files are now); stores from before
    agents (or episode streams) were recorded, without them."""
    if "stream" not in have:  # stored before campaigns had their own episode streams: resumed on the old rule
        wanted = {k: v for k, v in wanted.items() if k != "stream"}
    if "agent" not in have:
        return have, {k: v for k, v in wanted.items() if k != "agent"}
    before, after = have.get("agent") or {}, wanted.get("agent") or {}
    if before.get("kind") == after.get("kind") == "python" and not before.get("sha256"):  # recorded before parameters were hashed
        wanted = {**wanted, "agent": {**after, "sha256": None}}
    same = lambda agent: agent and agent_identity(agent)  # noqa: E731
    return {**have, "agent": same(have.get("agent"))}, {**wanted, "agent": same(wanted.get("agent"))}
