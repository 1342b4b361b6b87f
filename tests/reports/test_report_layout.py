"""The report reads like a result: headline numbers first, figures next, provenance last and
folded, no raw dicts in its tables, and the command that opens the same run in the explorer."""

from __future__ import annotations

import json
import re

from worldagent.reports.html import SECTIONS, build_report
from worldagent.reports.provenance import settings_text
from worldagent.reproduce.manifest import Manifest

STRUCTURE = {"total_curvature": {"generator": 12.99151906, "dataset": 13.8333957, "relative_difference": -0.0608582808}}


def small_run(tmp_path):
    """A run whose generator phase finished (its quality.json has nested figures); nothing else ran."""
    manifest = Manifest.open(tmp_path)
    manifest.data.update(preset="tiny", seed=0, envs=["racing"], config={"seed": 0}, versions={"jax": "0"}, device="cpu")
    manifest.start("racing/generator", {"vae_epochs": 3, "hidden": [64, 32], "options": {"observation": "route"}})
    manifest.finish("racing/generator", {"summary": "3 epochs"})
    quality = {
        "reconstruction": {"vae": {"accuracy": 0.9912345, "iou": 0.93}, "mean_image": {"accuracy": 0.96, "iou": 0.73}, "worlds": 100},
        "training": {"epochs": 3, "final": {"holdout_loss": 109.23798370361328}},
        "racing": {"self_mapping_rate": 0.9488, "structure": STRUCTURE},
    }
    (tmp_path / "racing" / "generator").mkdir(parents=True)
    (tmp_path / "racing" / "generator" / "quality.json").write_text(json.dumps(quality))
    return tmp_path


def test_headlines_come_first_and_provenance_last_folded(tmp_path):
    page = build_report(small_run(tmp_path)).read_text()
    anchors = [match for match in re.findall(r'<section id="([a-z]+)">', page)]
    assert anchors == [anchor for anchor, _ in SECTIONS]
    assert anchors[:2] == ["departures", "headline"] and anchors[-1] == "provenance"
    provenance = page.split('<section id="provenance">')[1]
    assert provenance.count("<details>") == 1 and "<table>" in provenance.split("<details>")[1]
    assert f"worldagent explore {tmp_path}" in page.split('<section id="random">')[0]  # said with the headline numbers


def test_no_table_cell_holds_a_raw_dict_or_an_unrounded_float(tmp_path):
    page = build_report(small_run(tmp_path)).read_text()
    cells = re.findall(r"<td[^>]*>(.*?)</td>", page)
    assert cells and not [c for c in cells if "{" in c or "[" in c]
    assert not [c for c in cells if re.search(r"\d\.\d{5,}", c)]
    assert "<td>total curvature</td><td>12.99</td><td>13.83</td><td>-6.09</td>" in page  # the structure, as a table of its own


def test_phase_settings_read_as_text():
    assert settings_text({"episodes": 300, "seeds": [0, 1], "options": {"tagger": [0]}, "rate": 0.000123456}) == (
        "episodes 300, options.tagger 0, rate 0.0001235, seeds 0 1"
    )


def test_the_generators_warnings_and_latent_figures_are_shown(tmp_path):
    run = small_run(tmp_path)
    path = run / "racing" / "generator" / "quality.json"
    quality = json.loads(path.read_text())
    warning = "collapsed: 0 of 10 latent dimensions active, KL 0.0087 nats in all; G(z) barely depends on z — retrain with a larger --free-bits"
    quality["warnings"] = [warning]
    quality["racing"]["latent"] = {"kl_total": 0.0087, "active_units": 0, "kl_per_dim": [0.00087] * 10}
    quality["racing"]["sensitivity"] = {"mean_changed_world_share": 0.0}
    path.write_text(json.dumps(quality))
    page = build_report(run).read_text()
    generator = page.split('<section id="generator">')[1].split("</section>")[0]
    assert "<ul class='warning'><li>collapsed: 0 of 10" in generator and "--free-bits" in generator
    departures = page.split('<section id="departures">')[1].split("</section>")[0]  # said first, not only deep in the page
    assert "data-flag='generator-warning' data-env='racing'>racing: the generator failed its own gate: collapsed: 0 of 10" in departures
    assert "<td>latent: KL, nats (active units)</td><td>0.0087 (0 of 10)</td>" in generator
    assert "<td>worlds changed by a ±1 move along z</td><td>0</td>" in generator
