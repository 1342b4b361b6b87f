"""The report's "Preset" section shows the budgets of only the environments the run ran (issue 30, item 4)."""

from __future__ import annotations

from worldagent.reports.provenance import overview, preset_of_run


def test_preset_section_shows_only_the_environments_run(tmp_path):
    config = {"name": "tiny", "envs": {"racing": {"worlds": 128}, "harvest": {"worlds": 256}, "lavagrid": {"worlds": 64}}, "seed": 0}
    assert preset_of_run(config, ["lavagrid"]) == {"name": "tiny", "envs": {"lavagrid": {"worlds": 64}}, "seed": 0}
    assert preset_of_run({"name": "old"}, ["racing"]) == {"name": "old"}  # a manifest without per-env budgets is shown as is
    page = overview({"preset": "tiny", "envs": ["lavagrid"], "config": config, "phases": {}}, tmp_path)
    preset = page.split("<h3>Preset</h3>")[1]
    assert "lavagrid" in preset and "racing" not in preset and "harvest" not in preset
