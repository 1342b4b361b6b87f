"""Where a run departs from the paper: the headline numbers that disagree, each with the causes the run's own record shows.

The report opens with this box (``departures_section``), so a reader sees first which of the paper's
numbers this run did not reproduce, and what may have caused it. Causes come only from facts the run
recorded: every setting its phases recorded (``manifest.json``'s ``full_config``) that differs from the
env's ``paper`` preset's recorded beside it (``paper_config``; ``setting_differences``, the one place that
computes "what differs from the paper":
algorithm, env options such as racing's observation, VAE epochs, training episodes, budgets, repeats,
seeds, repair), the generator's own gate warnings (``worldagent.worlds.quality.diagnose``), a
normalisation the paper does not spell out, and one seed per arm. A number is called a real
difference only when none of these applies; each gap links to the section that holds its numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from worldagent.envs import registry
from worldagent.reports.noise import share_note
from worldagent.reports.page import esc, fmt
from worldagent.reports.results import Headline

RELATIVE_GAP = 0.25  # ours differs when it is off by more than a quarter of the paper's value ...
ABSOLUTE_GAP = 0.05  # ... and by more than this (rates and normalised rewards live in [0, 1])
SECTION = {"random": "random", "min": "strategic", "max": "strategic", "influence": "influence"}
UNRECORDED = "(none recorded)"
# (phase, config field) -> (words, counted): counted settings read "1,000 training episodes", the others "algorithm ppo".
WORDS = {
    ("dataset", "worlds"): ("dataset worlds", True),
    ("generator", "epochs"): ("VAE epochs", True),
    ("generator", "hidden"): ("VAE hidden widths", False),
    ("generator", "batch_size"): ("VAE batch size", False),
    ("generator", "repair"): ("repair of G(z)", False),
    ("agent", "algo"): ("training algorithm", False),
    ("agent", "episodes"): ("training episodes", True),
    ("agent", "train_envs"): ("environments stepped in parallel (0: the algorithm's default)", False),
    ("agent", "learning_starts"): ("transitions before learning starts", False),
    ("random", "worlds"): ("random worlds", True),
    ("strategic", "budget"): ("worlds searched", True),
    ("strategic", "optimiser"): ("search optimiser", False),
    ("compare", "budget"): ("worlds per optimiser and seed", True),
    ("compare", "bo_budget"): ("worlds per Bayesian-optimisation seed", True),
    ("compare", "seeds"): ("seeds per optimiser", True),
    ("influence", "candidates"): ("candidate worlds", True),
    ("influence", "episodes"): ("training episodes per agent", True),
    ("influence", "eval_worlds"): ("evaluation worlds", True),
    ("influence", "seeds"): ("seeds per arm", True),
    ("influence", "search_budget"): ("extra search evaluations", True),
    ("influence", "algo"): ("training algorithm", False),
    ("influence", "confirm"): ("fresh episodes confirming each selected world", True),
    ("atlas", "budget"): ("atlas worlds", True),
    ("atlas", "failure_worlds"): ("worlds per failure-rate estimate", True),
}
NESTED = {"options": "env option", "settings": "training setting", "curriculum": "curriculum"}  # a dotted name's first part, said
IGNORED = ("seed",)  # the paper preset's seed is ours, not the paper's: a different seed departs from nothing


@dataclass(frozen=True)
class Departure:
    """One headline number that disagrees with the paper's, what may cause it, and where to read more."""

    row: Headline
    cause: str
    anchor: str


@dataclass(frozen=True)
class SettingDifference:
    """One setting of a run's phase that differs from the env's ``paper`` preset.

    Attributes:
        phase: the phase whose config holds it (``agent``, ``generator``, ...).
        name: its field, dotted where nested (``options.observation``).
        ours: the run's recorded value; ``paper``: the paper preset's (``UNRECORDED`` where one side has none).
    """

    phase: str
    name: str
    ours: Any
    paper: Any

    @property
    def counted(self) -> bool:
        return WORDS.get((self.phase, self.name), ("", False))[1]

    @property
    def words(self) -> str:
        """What the setting is, in words (``WORDS``; else its name, ``options.observation`` as "env option observation")."""
        if (self.phase, self.name) in WORDS:
            return WORDS[(self.phase, self.name)][0]
        head, _, rest = self.name.partition(".")
        return f"{NESTED.get(head, head)} {rest}".strip().replace("_", " ") if rest else self.name.replace("_", " ")

    def shown(self, value: Any) -> str:
        """A value as the text says it: a counted list by its length, None as "the default", lists space-separated."""
        if value is None:
            return "the default"
        if isinstance(value, (list, tuple)):
            return f"{len(value):,}" if self.counted else (" ".join(self.shown(v) for v in value) or "none")
        if isinstance(value, dict):
            return ", ".join(f"{k} {self.shown(v)}" for k, v in value.items()) or "none"
        return fmt(value)

    def text(self) -> str:
        """ "1,000 training episodes (paper preset: 5,000)", or "training algorithm ppo (paper preset: acktr)"."""
        ours, theirs = self.shown(self.ours), self.shown(self.paper)
        said = f"{ours} {self.words}" if self.counted and isinstance(self.ours, (int, list)) else f"{self.words} {ours}"
        return f"{said} (paper preset: {theirs})"


def differs(ours: float | None, paper: float | None) -> bool:
    """Ours and the paper's disagree: they have opposite signs, or lie apart by more than a quarter of the paper's value (and 0.05)."""
    if ours is None or paper is None or not (np.isfinite(ours) and np.isfinite(paper)):
        return False
    if ours * paper < 0:
        return True
    return abs(ours - paper) > max(ABSOLUTE_GAP, RELATIVE_GAP * abs(paper))


def family(key: str) -> str:
    """``harvest.influence.conflict_default`` -> ``influence`` (``min``/``max`` -> ``strategic``)."""
    part = key.split(".")[1]
    return "strategic" if part in ("min", "max") else part


def seeds_of(res: dict) -> int | None:
    """How many seeds trained each influence arm (None: no influence phase)."""
    config = (res.get("influence") or {}).get("config") or res["phases"].get("influence", {}).get("config") or {}
    return len(config["seeds"]) if "seeds" in config else None


def flat(config: dict, prefix: str = "") -> dict[str, Any]:
    """{"options.observation": "rays", ...}: nested settings dotted, so each is compared and named on its own."""
    out: dict[str, Any] = {}
    for key, value in config.items():
        if isinstance(value, dict) and value:
            out.update(flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def setting_differences(phase: str, entry: dict) -> list[SettingDifference]:
    """Every setting a phase recorded (``full_config``) that differs from the paper preset's, recorded beside it by
    ``reproduce`` (empty: none differs, or the manifest holds no paper-preset settings)."""
    ours, theirs = entry.get("full_config"), entry.get("paper_config")
    if not ours or not theirs:
        return []
    ours, theirs = flat(ours), flat(theirs)
    names = [name for name in dict.fromkeys([*theirs, *ours]) if name not in IGNORED]
    return [
        SettingDifference(phase, name, ours.get(name, UNRECORDED), theirs.get(name, UNRECORDED))
        for name in names
        if ours.get(name, UNRECORDED) != theirs.get(name, UNRECORDED)
    ]


def run_differences(res: dict) -> list[SettingDifference]:
    """Every setting of every recorded phase of one env's run that differs from its paper preset, in pipeline order."""
    return [d for phase, entry in res["phases"].items() for d in setting_differences(phase, entry)]


def phases_behind(phases: dict, phase: str) -> list[str]:
    """``phase`` and every phase it is computed from (each phase's recorded ``depends``), in pipeline order."""
    found, todo = set(), [phase]
    while todo:
        name = todo.pop()
        if name not in found:
            found.add(name)
            todo.extend(phases.get(name, {}).get("depends", ()))
    return [name for name in phases if name in found]


def generator_warnings(res: dict) -> list[str]:
    """The generator's own gate warnings (``worlds.quality.diagnose``: collapsed, overfit, inert, narrow, shifted), as
    its phase recorded them and as ``quality.json`` holds them."""
    recorded = (res["phases"].get("generator", {}).get("outputs") or {}).get("warnings") or []
    return list(dict.fromkeys([*recorded, *((res.get("quality") or {}).get("warnings") or [])]))


def generator_waiver(res: dict) -> str | None:
    """Why a generator its gate rejected was used anyway (the gate's verdict, ``worlds.quality.gate``, as the generator
    phase records it: a tiny preset's toy budgets, ``--accept-generator``); None: no waiver recorded."""
    outputs = res["phases"].get("generator", {}).get("outputs") or {}
    verdict = outputs.get("gate") or (res.get("quality") or {}).get("gate") or {}
    return verdict.get("waiver") if isinstance(verdict, dict) else None


def causes(row: Headline, results: dict) -> list[str]:
    """What the run's own record shows that may move this number away from the paper's: one seed per arm, the
    generator's gate warnings, each setting that differs from the paper preset in a phase the number is computed
    from, a normalisation the paper does not give, and settings a phase did not record."""
    env = row.key.split(".")[0]
    res, spec, kind = results[env], registry.get(env), family(row.key)
    found = []
    if kind == "influence" and seeds_of(res) == 1:
        found.append("one seed per arm: a single agent per arm cannot show the direction of a change")
    found += [f"the generator failed its own gate ({line.split(':')[0]})" for line in generator_warnings(res)]
    behind = phases_behind(res["phases"], kind) if kind in res["phases"] else []
    settings = [
        d.text()
        for phase in behind
        for d in setting_differences(phase, res["phases"][phase])
        if not (d.phase == "influence" and d.name == "seeds" and seeds_of(res) == 1)  # said above
    ]
    if settings:
        found.append("settings unlike the paper preset: " + ", ".join(dict.fromkeys(settings)))
    unrecorded = [phase for phase in behind if not res["phases"][phase].get("paper_config")]
    if "paper" not in spec.presets or unrecorded:
        what = f"{env} has no paper preset" if "paper" not in spec.presets else f"the {', '.join(unrecorded)} phase recorded no paper-preset settings"
        found.append(f"unexplained: {what}, so nothing says whether the run matched the paper's")
    if ("normalised" in row.key or "reward_change" in row.key) and spec.metrics.bounds is None:
        found.append("normalised by this run's best single episode, a rule the paper does not give")
    return found


def likely_cause(row: Headline, results: dict) -> str:
    """The causes of ``causes`` joined; a real difference only when the run's record shows none."""
    found = causes(row, results)
    return "; ".join(found) or "unexplained by the run's settings: every one matches the paper's preset, a real difference; see the section"


def departures(rows: list[Headline], results: dict) -> list[Departure]:
    """The headline rows where ours and the paper's differ (``differs``), each with ``likely_cause`` and its section."""
    return [
        Departure(row, likely_cause(row, results), SECTION.get(row.key.split(".")[1], "headline")) for row in rows if differs(row.ours, row.paper)
    ]


def one_seed_notes(results: dict) -> list[str]:
    """A line per env whose influence arms trained with one seed: what its changes can and cannot say."""
    notes = []
    for env, res in results.items():
        if seeds_of(res) != 1 or "influence" not in res:
            continue
        summary = res["influence"].get("summary", {})
        changes = ", ".join(
            f"{name.replace('_', ' ')} {fmt(v['default']['mean'], 3)} → {fmt(v['influenced']['mean'], 3)}"
            for name, v in summary.items()
            if name in registry.get(env).metrics.highlighted
        )
        notes.append(
            f"{env}: the influence phase trained one seed per arm ({changes}); one seed cannot show which way influencing moves a metric "
            f"(the paper's preset trains {len(registry.get(env).presets.get('paper', {}).get('influence_seeds', ())) or 'several'})."
        )
    return notes


def share_notes(results: dict) -> dict[str, str]:
    """{env: one line}: the world's share of each env's main metric on its random campaign (``reports.noise.share_note``)."""
    shares = {env: (res.get("random") or {}).get("share") for env, res in results.items()}
    notes = {env: share_note(env, share, registry.get(env).metrics.main) for env, share in shares.items() if share}
    return {env: line for env, line in notes.items() if line}


def settings_box(results: dict, preset: str | None) -> str:
    """The preset's line and, folded, every setting of the run that differs from the paper preset (``run_differences``)."""
    found = {env: run_differences(res) for env, res in results.items()}
    count = sum(len(d) for d in found.values())
    unmatched = [env for env in results if "paper" not in registry.get(env).presets]
    named = f"the <code>{esc(preset)}</code> preset" if preset else "its own settings"
    if not count:
        line = f"<p>This run used {named}; every setting its phases recorded matches the paper's preset.</p>"
    else:
        line = (
            f"<p>This run used {named}: <strong>{count} of its settings {'differs' if count == 1 else 'differ'} from the paper's preset</strong> "
            "(each is named below as a possible cause where a number depends on it); "
            "<code>worldagent reproduce --preset paper</code> runs the paper's.</p>"
        )
    rows = "".join(
        f"<tr data-setting='{esc(env)}/{esc(d.phase)}/{esc(d.name)}'><td>{esc(env)}</td><td>{esc(d.phase)}</td><td>{esc(d.words)}</td>"
        f"<td>{esc(d.shown(d.ours))}</td><td>{esc(d.shown(d.paper))}</td></tr>"
        for env, differences in found.items()
        for d in differences
    )
    table = (
        f"<details><summary>The {count} {'setting that differs' if count == 1 else 'settings that differ'} from the paper's preset</summary>"
        "<table><thead><tr><th>env</th><th>phase</th><th>setting</th><th>ours</th><th>paper's preset</th></tr></thead>"
        f"<tbody>{rows}</tbody></table></details>"
        if count
        else ""
    )
    none = "".join(f"<p>{esc(env)} has no paper preset: nothing to set its settings beside.</p>" for env in unmatched)
    return line + table + none


def generator_box(results: dict) -> str:
    """Each env's generator gate warnings (``generator_warnings``): every number of that env is drawn from that G(z)."""
    waived = {env: f" (used anyway: {waiver})" if (waiver := generator_waiver(res)) else "" for env, res in results.items()}
    lines = "".join(
        f"<li data-flag='generator-warning' data-env='{esc(env)}'>{esc(env)}: the generator failed its own gate: {esc(line + waived[env])}</li>"
        for env, res in results.items()
        for line in generator_warnings(res)
    )
    return f"<ul class='warning'>{lines}</ul>" if lines else ""


def departures_section(rows: list[Headline], results: dict, preset: str | None = None) -> str:
    """The report's opening box: the settings unlike the paper's, the generator's gate warnings, each number that departs
    from the paper with its possible causes and its section; one-seed warnings; the world's share."""
    found = departures(rows, results)
    compared = [r for r in rows if r.ours is not None and r.paper is not None]
    if not compared:
        head = "<p>No headline number of this run can be set beside the paper's yet (the phases that make them have not run).</p>"
    elif not found:
        head = f"<p>All {len(compared)} numbers the paper reports lie within a quarter of its values (and 0.05).</p>"
    else:
        head = (
            f"<p><strong>{len(found)} of the {len(compared)} numbers the paper reports differ from ours</strong> "
            f"(opposite sign, or apart by more than a quarter of the paper's value and {ABSOLUTE_GAP}):</p>"
        )
    body = "".join(
        f"<tr data-departure='{esc(d.row.key)}'><td>{esc(d.row.label)}</td><td class='num'>{fmt(d.row.ours, 3)}</td>"
        f"<td class='num'>{fmt(d.row.paper)}</td><td>{esc(d.cause)}</td><td><a href='#{d.anchor}'>{esc(d.anchor)}</a></td></tr>"
        for d in found
    )
    table = (
        "<table><thead><tr><th>quantity</th><th>ours</th><th>paper</th><th>possible causes (the run's own record)</th><th>section</th></tr></thead>"
        f"<tbody>{body}</tbody></table>"
        if found
        else ""
    )
    notes = "".join(f"<li data-flag='one-seed'>{esc(line)}</li>" for line in one_seed_notes(results))
    shares = "".join(f"<li data-share-env='{esc(env)}'>{esc(line)}</li>" for env, line in share_notes(results).items())
    share_list = (
        "<p>How much of an episode's outcome belongs to the world (the paper does not measure it; "
        "<a href='#random'>random evaluation</a>):</p>"
        f"<ul class='share'>{shares}</ul>"
        if shares
        else ""
    )
    return (
        f"<div class='departures'>{settings_box(results, preset)}{generator_box(results)}{head}{table}"
        + (f"<ul class='warning'>{notes}</ul>" if notes else "")
        + share_list
        + "</div>"
    )
