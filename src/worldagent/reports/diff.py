"""``worldagent diff``'s result as text: a Markdown report section (``diff.md``, a CI job summary) and console lines."""

from __future__ import annotations

import math

from worldagent.analysis.diff import interval_test_disagreement, tail_warning
from worldagent.analysis.noise import repeats_for
from worldagent.reports.noise import LUCK_SHARE, RELIABLE

CONSOLE_ROWS = 5  # regressed worlds the console lists (diff.md: the summary's limit)


def number(value, digits: int = 4) -> str:
    """A number for a table: 4 significant digits, "n/a" for None or NaN."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return f"{value:.{digits}g}" if isinstance(value, float) else str(value)


def interval(row: dict, low: str = "low", high: str = "high") -> str:
    return f"[{number(row[low])}, {number(row[high])}]"


def place(row: dict) -> str:
    """ "diff-prior-s0 2/18": where a world is stored (campaign, generation/slot): a slot alone names no world."""
    return f"{row['campaign']} {row['generation']}/{row['slot']}"


def cut_note(shown: int, total: int) -> str:
    """ " (20 of 25 shown)" when a list leaves some out, else ""."""
    return f" ({shown} of {total} shown)" if total > shown else ""


def agent_name(record: dict) -> str:
    return f"{record.get('path')} ({record.get('kind')})"


def metric_table(worlds: dict) -> list[str]:
    rows = ["| metric | A | B | B − A | 95% interval |", "|---|---|---|---|---|"]
    for name, row in worlds["metrics"].items():
        rows.append(f"| {name} | {number(row['a'])} | {number(row['b'])} | {number(row['difference'])} | {interval(row)} |")
    return rows


def failure_lines(worlds: dict) -> list[str]:
    failure = worlds["failure"]
    a, b, difference = failure["a"], failure["b"], failure["difference"]
    return [
        f"P(failure), failure = `{failure['event']}`: A {number(a['p'])} {interval(a)}, B {number(b['p'])} {interval(b)}; "
        f"B − A {number(difference['value'])} {interval(difference)} (Tango's paired score interval; exact McNemar p = {number(difference['p_value'], 3)}).",
        f"{failure['regressed']} worlds regressed (fail under B, pass under A){distinct_note(failure)}, {failure['improved']} improved, "
        f"of {failure['worlds']} (the sampled worlds' own episodes).",
    ] + disagreement_lines(failure)


def disagreement_lines(failure: dict) -> list[str]:
    """The line saying why Tango's interval and the exact test disagree, where they do (``analysis.diff``)."""
    said = interval_test_disagreement(failure["difference"], failure["regressed"] + failure["improved"])
    return [f"Note: {said}"] if said else []


def noise_lines(worlds: dict) -> list[str]:
    """A warning when this env's outcome on these worlds is mostly dice (the world's share below ``LUCK_SHARE``,
    ``differential.world_noise``): a world's B − A is then mostly luck. [] when not measured (one episode per world)."""
    noise = worlds.get("noise") or {}
    named = {f"A's {noise.get('metric')}": noise.get("a"), f"B's {noise.get('metric')}": noise.get("b")}
    named[f"B's failure `{worlds['failure']['event']}`"] = noise.get("failure_b")
    noisy = {what: share for what, share in named.items() if share and share.get("icc") is not None and share["icc"] < LUCK_SHARE}
    if not noisy:
        return []
    said = "; ".join(f"{what} {number(s['icc'], 2)} [{number(s['low'], 2)}, {number(s['high'], 2)}]" for what, s in noisy.items())
    more = [n for n in (repeats_for(s["icc"], RELIABLE) for s in noisy.values()) if n]
    fix = (
        f"pass --repeats {max(more)} (a world's score of reliability {RELIABLE})"
        if more and max(more) > noise["repeats"]
        else "compare on more worlds"
    )
    return [
        f"Warning: on these worlds the outcome is mostly dice (the world's share of one episode's variance, below {LUCK_SHARE}: {said}; "
        f"{noise['repeats']} episodes per world): a world's B − A, and whether it regressed, is mostly luck; read the regressed "
        f"worlds as candidates (the confirmation replays them on fresh episodes), or {fix}."
    ]


def distinct_note(failure: dict) -> str:
    """ " (9 distinct worlds)" where repair made some sampled worlds one world, else ""."""
    distinct = failure.get("regressed_distinct")
    return "" if distinct is None or distinct == failure["regressed"] else f" ({distinct} distinct worlds)"


def cvar_line(worlds: dict) -> str:
    risk = worlds["cvar"]
    warning = risk.get("warning", tail_warning(risk["tail"], risk["alpha"]))  # a diff.json written before the warning was kept
    return (
        f"α-CVaR ({risk['alpha']:.0%} worst worlds, {risk['tail']} of them) of {risk['metric']}: A {number(risk['a'])}, B {number(risk['b'])}; "
        f"B − A {number(risk['difference'])} {interval(risk)} (BCa bootstrap over worlds)." + (f" Warning: {warning}" if warning else "")
    )


def regressed_table(rows: list[dict], title: str, total: int) -> list[str]:
    """The regressed worlds listed (at most the summary's limit of ``total``), each with its generation and slot."""
    if not rows:
        return []
    shown = list(rows[0]["a"])
    head = ["| world | log N(z; 0, I) | " + " | ".join(f"{m} A → B" for m in shown) + " | nearest world where B passes |"]
    head.append("|---" * (len(shown) + 3) + "|")
    for row in rows:
        near = row["nearest_passing"]
        where = "none" if near is None else f"{place(near)} (distance {number(near['distance'], 3)})"
        changes = " | ".join(f"{number(row['a'][m])} → {number(row['b'][m])}" for m in shown)
        head.append(f"| {place(row)} | {number(row['log_prior'])} | {changes} | {where} |")
    return [f"**{title}**{cut_note(len(rows), total)}", "", *head]


def search_lines(search: dict) -> list[str]:
    best = search["best"]
    direction = "highest" if search["maximize"] else "lowest"
    first = search["first_regressed"]
    found = f"the first at evaluation {first}" if first else "none"
    evaluations = search.get("regressed_evaluations", search["regressed"])
    counted = f"{search['regressed']} distinct regressed worlds found" + (
        f" ({evaluations} evaluations)" if evaluations != search["regressed"] else ""
    )
    lines = [
        f"Differential search ({search['search']}, campaign `{search['campaign']}`): {search['evaluations']} worlds, {search['episodes']} episodes, "
        f"{direction} {search['metric']}(B) − {search['metric']}(A).",
        f"Most extreme world: {place(best)}, {search['metric']} A {number(best['a'])} → B {number(best['b'])} "
        f"(B − A {number(best['score'])}, the search's figure); {counted}, {found}.",
    ]
    if best.get("prior"):  # issue 48: where the world lies under G's prior, and where the search was allowed to go
        from worldagent.search.prior import bound_text, summary_text

        lines.append(f"Under the prior: {summary_text(best['prior'])}; searched {bound_text(search.get('prior_bound'), best['prior']['dim'])}.")
    confirmed = search.get("confirmed")
    if confirmed:
        drop = confirmed["largest_drop"]
        lines.append(
            f"Confirmed on {confirmed['repeats']} fresh episodes per agent (A and B on the same keys): the most extreme world's drop "
            f"{number(drop['mean'])} [{number(drop['low'])}, {number(drop['high'])}] (found {number(search['largest_drop'])}); "
            + confirmed_count(confirmed)
        )
    return lines


def confirmed_count(confirmed: dict) -> str:
    """ "3 of 12 distinct regressed worlds checked are confirmed regressed (…)"."""
    checked, found = confirmed["checked"], confirmed["found_regressed"]
    of = f"{checked} distinct regressed worlds checked" + (f" (the likeliest {checked} of {found})" if checked < found else "")
    return (
        f"{confirmed['regressed']} of {of} are confirmed regressed (B's confirmed interval fails `{confirmed['event']}` and A's passes; "
        f"B confirmed failing on {confirmed['b_confirmed_failing']}, A confirmed passing on {confirmed['a_confirmed_passing']})."
    )


def side_text(side: dict, metric: str) -> str:
    """ "0.75 → 0.41 [0.29, 0.53]": one agent's found (the selection's) and confirmed mean of ``metric``."""
    found, confirmed = side["found"][metric], side["confirmed"][metric]
    return f"{number(found['mean'])} → {number(confirmed['mean'])} [{number(confirmed['low'])}, {number(confirmed['high'])}]"


def confirmed_table(confirmed: dict | None, title: str) -> list[str]:
    """The confirmed worlds: each agent's found → confirmed figure of each metric, the paired B − A failure rate, the verdict."""
    if not confirmed or not confirmed["worlds"]:
        return []
    shown = list(confirmed["worlds"][0]["a"]["found"])
    head = "| world | " + " | ".join(f"{m} A: found → confirmed | {m} B: found → confirmed" for m in shown)
    lines = [
        f"**{title}** ({confirmed['repeats']} fresh episodes per agent, the same keys for both)",
        "",
        head + " | B − A failure rate | regressed? |",
    ]
    lines.append("|---" * (2 * len(shown) + 3) + "|")
    for row in confirmed["worlds"]:
        cells = " | ".join(f"{side_text(row['a'], m)} | {side_text(row['b'], m)}" for m in shown)
        difference = row["failure_rate_difference"]
        verdict = "confirmed" if row["confirmed_regressed"] else "not confirmed"
        lines.append(f"| {place(row)} | {cells} | {number(difference['mean'])} {interval(difference)} | {verdict} |")
    return lines


def gate_lines(gate: dict | None) -> list[str]:
    if gate is None:
        return []
    rows = [f"`{row['condition']}`: {number(row['value'])} → {'FAILS' if row['holds'] else 'passes'}" for row in gate["conditions"]]
    return [f"Gate: **{'failed' if gate['failed'] else 'passed'}**.", "", *[f"- {row}" for row in rows]]


def markdown(result: dict) -> str:
    """The report section of a ``differential.diff`` result (with its gate, if any)."""
    agents = result["agents"]
    lines = [
        f"## Which worlds got worse? ({result['env']})",
        "",
        f"A (old): {agent_name(agents['a'])}; B (new): {agent_name(agents['b'])}. "
        f"Both played every world with the same episode keys (seed {result['seed']}, {result['repeats']} episodes per world); "
        f"{result['episodes']:,} episodes in all.",
        "",
    ]
    worlds = result.get("worlds")
    if worlds:
        lines += [f"On {worlds['worlds']} worlds ({source_text(result['source'])}), campaign `{worlds['campaign']}`:", "", *metric_table(worlds), ""]
        lines += [*failure_lines(worlds), "", cvar_line(worlds), "", *noise_lines(worlds), ""]
        title = "Regressed worlds, likeliest under the prior first"
        lines += [*regressed_table(worlds["regressed_worlds"], title, worlds["failure"]["regressed"]), ""]
        if worlds.get("confirmed"):
            lines += [f"Confirmed: {confirmed_count(worlds['confirmed'])}", ""]
            lines += [*confirmed_table(worlds["confirmed"], "Regressed worlds confirmed for A and B"), ""]
    if result.get("search"):
        lines += [*search_lines(result["search"]), ""]
        title = "Regressed worlds the search found (one row per distinct world)"
        lines += [*regressed_table(result["search"]["regressed_worlds"], title, result["search"]["regressed"]), ""]
        lines += [*confirmed_table(result["search"].get("confirmed"), "The search's regressed worlds confirmed for A and B"), ""]
    lines += gate_lines(result.get("gate"))
    return "\n".join(lines).rstrip() + "\n"


def source_text(source: dict | None) -> str:
    if not source:
        return "none"
    if "prior" in source:
        return f"G(z), z ~ N(0, I): {source['prior']} samples"
    if "campaign" in source:
        return f"campaign {source['campaign']} of {source['store']}"
    return "datasets " + ", ".join(source.get("datasets", []))


def console_lines(result: dict) -> list[str]:
    """The few lines ``worldagent diff`` prints."""
    lines = []
    worlds = result.get("worlds")
    if worlds:
        main = worlds["cvar"]["metric"]
        row = worlds["metrics"][main]
        lines.append(
            f"{worlds['worlds']} worlds x {worlds['repeats']} episodes x 2 agents ({worlds['episodes']:,} episodes): "
            f"{main} A {number(row['a'])}, B {number(row['b'])}, B − A {number(row['difference'])} {interval(row)}"
        )
        lines += failure_lines(worlds) + [cvar_line(worlds)] + noise_lines(worlds)
        if worlds.get("confirmed"):
            lines.append(f"confirmed on {worlds['confirmed']['repeats']} fresh episodes per agent: {confirmed_count(worlds['confirmed'])}")
        listed, total = worlds["regressed_worlds"], worlds["failure"]["regressed"]
        for row in listed[:CONSOLE_ROWS]:
            near = row["nearest_passing"]
            where = "" if near is None else f"; nearest where B passes: {place(near)} (distance {number(near['distance'], 3)})"
            lines.append(f"  regressed: {place(row)}, log prior {number(row['log_prior'])}{where}")
        if total > min(len(listed), CONSOLE_ROWS):
            lines.append(f"  ({min(len(listed), CONSOLE_ROWS)} of {total} regressed worlds shown; diff.md lists {len(listed)})")
    if result.get("search"):
        lines += search_lines(result["search"])
    for row in (result.get("gate") or {}).get("conditions", []):
        lines.append(f"gate: {row['condition']} (value {number(row['value'])}) {'FAILS' if row['holds'] else 'passes'}")
    return lines
