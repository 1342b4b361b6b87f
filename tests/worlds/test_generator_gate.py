"""The main job never uses a generator its own gate rejects without saying so (issue 47 item 6).

``worlds.quality.gate`` turns ``diagnose``'s warnings into a verdict; the reproduce generator phase
refuses a rejected generator in one line (its figures written first) unless the preset accepts it
for a recorded reason, as the tiny preset does for its toy budgets.
"""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from toy_env import registered
from worldagent.errors import WorldagentError
from worldagent.reproduce import phases
from worldagent.reproduce.phases import EnvContext, dataset_phase, generator_phase
from worldagent.reproduce.presets import get_preset
from worldagent.worlds import quality
from worldagent.worlds.quality import gate, gate_kinds

OVERFIT = "overfit: held-out reconstruction no better than the mean world (NLL 208.3 vs 177.5 nats per world), training NLL 33.0: ..."
NARROW = "narrow: wall_share spreads under G(z) 41% as wide as in the dataset: ..."


def test_any_warning_rejects_and_only_a_stated_reason_waives():
    assert gate([]) == {"verdict": "passed", "warnings": []}
    assert gate([], "toy budgets") == {"verdict": "passed", "warnings": []}  # nothing to waive
    assert gate([OVERFIT, NARROW]) == {"verdict": "rejected", "warnings": [OVERFIT, NARROW]}
    assert gate([OVERFIT], "") == {"verdict": "rejected", "warnings": [OVERFIT]}  # an empty reason is no reason
    assert gate([OVERFIT], "toy budgets") == {"verdict": "waived", "warnings": [OVERFIT], "waiver": "toy budgets"}
    assert gate_kinds([OVERFIT, NARROW, NARROW]) == "overfit, narrow"


def test_the_tiny_preset_waives_its_gate_with_a_reason_and_the_others_do_not():
    assert "tiny" in get_preset("tiny").accept_generator
    assert get_preset("quick").accept_generator is None and get_preset("paper").accept_generator is None
    assert get_preset("quick").with_generator_accepted("checked by hand").accept_generator == "checked by hand"


@pytest.fixture(scope="module")
def toy_run(tmp_path_factory):
    """A run directory holding the toy env's tiny dataset (the generator phase trains on it)."""
    with registered() as spec:
        out = tmp_path_factory.mktemp("gate")
        preset = get_preset("tiny")
        dataset_phase(EnvContext(out, spec.name, preset, progress=False))
        yield out, spec.name, preset


@pytest.mark.integration
def test_the_generator_phase_refuses_a_rejected_generator_and_records_a_waived_one(toy_run, monkeypatch):
    out, env, tiny = toy_run
    monkeypatch.setattr(quality, "diagnose", lambda *args, **kwargs: [OVERFIT])  # the gate's finding, whatever this VAE is
    monkeypatch.setattr(phases, "QUALITY_SAMPLES", 50)  # figures of 50 draws: the verdict is what is tested
    with registered():
        with pytest.raises(WorldagentError, match=r"toy's generator fails its quality gate \(overfit; .*--accept-generator") as refused:
            generator_phase(EnvContext(out, env, replace(tiny, accept_generator=None), progress=False))
        assert "\n" not in str(refused.value)
        written = json.loads((out / env / "generator" / "quality.json").read_text())
        assert written["gate"] == {"verdict": "rejected", "warnings": [OVERFIT]}  # the figures are there to read
        outputs = generator_phase(EnvContext(out, env, tiny, progress=False))  # the VAE is reused, not retrained
    assert outputs["gate"] == {"verdict": "waived", "warnings": [OVERFIT], "waiver": tiny.accept_generator}
    assert "gate waived (overfit: expected at the tiny preset" in outputs["summary"]
    written = json.loads((out / env / "generator" / "quality.json").read_text())
    assert written["gate"] == outputs["gate"] and written["training"]["kept_epoch"] == 3  # 3 epochs, all within warm-up: the last


def test_accept_generator_on_the_command_line_is_the_recorded_reason():
    import json

    from typer.testing import CliRunner

    from worldagent.cli import app

    shown = {}
    for flags in ([], ["--accept-generator"]):
        result = CliRunner().invoke(app, ["reproduce", "--preset", "quick", "--env", "racing", "--show", *flags])
        assert result.exit_code == 0, result.output
        shown[bool(flags)] = json.loads(result.output)["accept_generator"]
    assert shown == {False: None, True: "--accept-generator"}
