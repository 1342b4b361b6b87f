"""benchmarks/device_check.py (issue 43): a cut-short GPU run still writes every section.

The sections themselves run in CI's smoke step (``.ci/run``); here no section runs (the budget is
spent before the first), so the test takes no JAX time.
"""

import importlib.util
import json
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_device_check():
    spec = importlib.util.spec_from_file_location("device_check", BENCHMARKS / "device_check.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_spent_budget_still_writes_every_section(tmp_path):
    device_check = load_device_check()
    assert device_check.main(["--out", str(tmp_path), "--budget", "0"]) == 0
    (written,) = tmp_path.glob("device-*.json")
    result = json.loads(written.read_text())
    assert list(result["sections"]) == list(device_check.SECTIONS)
    assert all("the budget ran out" in entry["skipped"] for entry in result["sections"].values())
    assert {"card", "driver", "cuda", "commit", "values", "headline"} <= set(result)


def test_smoke_fails_when_a_section_records_nothing(tmp_path):
    device_check = load_device_check()
    assert set(device_check.RECORDS) == set(device_check.SECTIONS)  # every section is checked in CI
    assert device_check.main(["--smoke", "--out", str(tmp_path), "--budget", "0"]) == 1
    assert (tmp_path / f"device-{device_check.card()['card']}-smoke.json").exists()
