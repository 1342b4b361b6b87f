"""The main job's influence phase trains on confirmed worlds, and records a selection none of which survives."""

from __future__ import annotations

from worldagent import experiments
from worldagent.influence.confirmation import NoneSurvived
from worldagent.reports.html import influence_section
from worldagent.reproduce.phases import EnvContext, influence_phase
from worldagent.reproduce.presets import get_preset


def test_a_selection_none_of_which_keeps_its_property_is_recorded_and_reported(tmp_path, monkeypatch):
    asked = {}

    def influence(*args, confirm, **kwargs):
        asked["confirm"] = confirm
        raise NoneSurvived("none of the 3 worlds with 'crash_rate > 0.5' kept it on 32 fresh episodes; loosen the selection", {"selected": 3})

    monkeypatch.setattr(experiments, "influence", influence)
    preset = get_preset("quick")
    context = EnvContext(tmp_path, "racing", preset, progress=False)
    context._cache["setup"] = None  # the stubbed influence never reads the agent
    outputs = influence_phase(context)

    assert asked["confirm"] == preset.influence_confirm > 0
    assert outputs["confirmation"] == {"selected": 3} and "none of the 3 worlds" in outputs["summary"]
    phases = {"influence": {"status": "done", "outputs": outputs}}
    page = influence_section(tmp_path, {"racing": {"phases": phases}})
    assert "skipped: none of the 3 worlds" in page and "no influence.json" not in page


def test_the_tiny_preset_trains_on_the_raw_selection_and_a_change_of_confirmation_reruns_the_phase():
    tiny, quick = get_preset("tiny"), get_preset("quick")
    assert tiny.influence_confirm == 0 and "confirm" not in tiny.phase_config("racing", "influence")
    assert quick.phase_config("racing", "influence")["confirm"] == quick.influence_confirm
