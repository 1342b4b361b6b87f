"""benchmarks/curriculum.py resumes from its committed results: an arm recorded under the same setup,
with its per-world values, is taken from there; any change to the setup trains it again.

Pure file round trips: no agent is trained.
"""

import json
from pathlib import Path

import numpy as np

from benchmark_scripts import load_benchmark


def agent(seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {"score": rng.random(6), "failing": (rng.random(6) > 0.5).astype(np.float64)}


def write_results(curriculum, out: Path, setup: dict) -> dict:
    worlds_of = {"dr": [agent(0), agent(1)], "plr": [agent(2), agent(3)]}
    per_seed = {arm: {seed: {"mean": float(values["score"].mean())} for seed, values in zip((0, 1), agents)} for arm, agents in worlds_of.items()}
    arms = {arm: {"curriculum": arm, "dirs": [f"/gone/{arm}/s0", f"/gone/{arm}/s1"]} for arm in worlds_of}
    curriculum.save_world_values(out, worlds_of)
    out.write_text(json.dumps({"setup": setup, "arms": arms, "per_seed": per_seed}))
    return worlds_of


def test_an_arm_recorded_under_the_same_setup_is_reused_with_its_world_values(tmp_path):
    curriculum = load_benchmark("curriculum")
    out, setup = tmp_path / "curriculum-racing.json", {"seeds": [0, 1], "generator_fingerprint": "abc", "target": {"maximize": None}}
    worlds_of = write_results(curriculum, out, setup)

    found = curriculum.recorded_arms(out, setup)

    assert set(found) == {"dr", "plr"}
    assert found["plr"]["per_seed"] == {
        0: {"mean": float(worlds_of["plr"][0]["score"].mean())},
        1: {"mean": float(worlds_of["plr"][1]["score"].mean())},
    }
    for mine, theirs in zip(found["plr"]["worlds"], worlds_of["plr"]):
        np.testing.assert_array_equal(mine["score"], theirs["score"])
        np.testing.assert_array_equal(mine["failing"], theirs["failing"])
    pooled = curriculum.pooled_vs_dr({arm: values["worlds"] for arm, values in found.items()})
    assert pooled == curriculum.pooled_vs_dr(worlds_of)  # the comparison is the same as before the reuse


def test_a_changed_setup_or_missing_values_reuse_nothing(tmp_path):
    curriculum = load_benchmark("curriculum")
    out, setup = tmp_path / "curriculum-racing.json", {"seeds": [0, 1], "generator_fingerprint": "abc"}
    write_results(curriculum, out, setup)

    assert curriculum.recorded_arms(out, {**setup, "generator_fingerprint": "another"}) == {}
    assert curriculum.recorded_arms(out, {**setup, "seeds": [0, 1, 2]}) == {}
    curriculum.worlds_file(out).unlink()
    assert curriculum.recorded_arms(out, setup) == {}
    assert curriculum.recorded_arms(tmp_path / "none.json", setup) == {}
