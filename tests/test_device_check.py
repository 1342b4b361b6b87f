"""benchmarks/device_check.py (issue 43): a cut-short GPU run still writes every section.

The sections themselves run in CI's smoke step (``.ci/run``); here no section runs (the budget is
spent before the first), so the test takes no JAX time.
"""

import json

from benchmark_scripts import load_benchmark


def test_a_spent_budget_still_writes_every_section(tmp_path):
    device_check = load_benchmark("device_check")
    assert device_check.main(["--out", str(tmp_path), "--budget", "0"]) == 0
    (written,) = tmp_path.glob("device-*.json")
    result = json.loads(written.read_text())
    assert list(result["sections"]) == list(device_check.SECTIONS)
    assert all("the budget ran out" in entry["skipped"] for entry in result["sections"].values())
    assert {"card", "driver", "cuda", "commit", "values", "headline"} <= set(result)


def test_smoke_fails_when_a_section_records_nothing(tmp_path):
    device_check = load_benchmark("device_check")
    assert set(device_check.RECORDS) == set(device_check.SECTIONS)  # every section is checked in CI
    assert device_check.main(["--smoke", "--out", str(tmp_path), "--budget", "0"]) == 1
    assert (tmp_path / f"device-{device_check.card()['card']}-smoke.json").exists()


def test_smoke_sections_run_to_completion_and_only_a_hung_one_is_cut():
    device_check = load_benchmark("device_check")
    for name in device_check.SECTIONS:  # a busy machine slows the smoke run's compilations: no cap but the hang guard
        assert device_check.section_cap("smoke", name, float("inf")) == device_check.HUNG_S
        assert device_check.section_cap("smoke", name, 40.0) == 40.0  # an explicit --budget still bounds it
    assert device_check.section_cap("full", "machine", 400.0) == device_check.CAPS["full"]["machine"]
    assert device_check.section_cap("full", "quick", 123.0) == 123.0


def test_a_smoke_section_cut_at_its_cap_has_hung_and_fails(tmp_path, monkeypatch):
    device_check = load_benchmark("device_check")
    (tmp_path / "device_sections.py").write_text("import time\nprint('compiling', flush=True)\ntime.sleep(60)\n")
    monkeypatch.setattr(device_check, "HERE", tmp_path)  # a section that never ends, in place of the real ones
    with open(tmp_path / "log", "w") as log:
        entry = device_check.run_section("machine", 0.5, tmp_path, True, log, {})
    assert entry["status"] == "failed"
    assert "hung" in entry["error"][-1] and "compiling" in entry["error"]
