"""The validation-sweep runner (benchmarks/nerf_sweep.py): every committed sweep result's choice follows
from its recorded scores under the sweep's rule and is what the tiny presets ship; tampered results are
caught; each rule picks as its text says on hand-made means.

Nothing here reruns a sweep (they take minutes to hours); the committed result files are the data.
"""

import copy
import importlib
import json
import sys
from pathlib import Path
from typing import Any

import pytest

BENCH = Path(__file__).parents[2] / "benchmarks"


@pytest.fixture(scope="module")
def ns() -> Any:
    """`benchmarks/nerf_sweep.py`, imported as the scripts import their siblings (by name)."""
    sys.path.insert(0, str(BENCH))
    try:
        return importlib.import_module("nerf_sweep")
    finally:
        sys.path.remove(str(BENCH))


def _result(ns: Any, key: str) -> dict[str, Any]:
    return json.loads((BENCH / "results" / f"{ns.SWEEPS[key].name}.json").read_text())


def test_every_committed_choice_follows_from_its_scores(ns: Any) -> None:
    assert set(ns.SWEEPS) == {"stage2", "stage1", "noise", "stage2-detail", "l1"}
    for key, spec in ns.SWEEPS.items():
        payload = _result(ns, key)
        assert ns.check(spec, payload) == [], key
        # the file records its rule and choice, as the table has them
        assert payload["choice"]["rule"] == spec.rule.text
        assert payload["choice"]["chosen"] == spec.recorded
        assert payload["choice"]["chosen_overrides"] == dict(spec.candidates[spec.recorded])
    assert ns.cmd_check([]) == 0


def test_a_choice_the_scores_do_not_support_is_caught(ns: Any) -> None:
    spec = ns.SWEEPS["noise"]
    payload = copy.deepcopy(_result(ns, "noise"))
    # shared noise made 1 dB worse on every pair, the means recomputed: the rule now picks per-view
    for pair in payload["pairs"]:
        pair["rows"]["shared noise"]["psnr_object_db"] -= 1.0
    payload["summary"]["means"] = spec.means(payload)
    problems = ns.check(spec, payload)
    assert any("the rule picks 'per-view noise'" in p for p in problems), problems


def test_edited_means_and_a_foreign_rule_are_caught(ns: Any) -> None:
    spec = ns.SWEEPS["stage1"]
    payload = copy.deepcopy(_result(ns, "stage1"))
    payload["summary"]["means"]["transfer r2"]["stlpips_crop"] += 0.01
    payload["choice"]["rule"] = "lowest ST-LPIPS"
    problems = ns.check(spec, payload)
    assert any("not the means of the recorded rows" in p for p in problems), problems
    assert any("rule" in p and "not the table's" in p for p in problems), problems

    l1 = ns.SWEEPS["l1"]
    payload = copy.deepcopy(_result(ns, "l1"))
    payload["fits"][0]["psnr_object_db"] += 5.0  # a row edited without its means
    assert any("not the means" in p for p in ns.check(l1, payload))


def test_record_rewrites_only_summary_and_choice(ns: Any) -> None:
    for key, spec in ns.SWEEPS.items():
        original = _result(ns, key)
        payload = copy.deepcopy(original)
        payload.pop("choice")
        ns._legacy_fields(spec, payload, spec.summary(payload))
        assert payload == original, key


def _means(**rows: tuple[float, float | None]) -> dict[str, dict[str, Any]]:
    return {n: {"psnr_object_db": p, "stlpips_crop": lp} for n, (p, lp) in rows.items()}


def test_the_rules_pick_as_their_text_says(ns: Any) -> None:
    s = ns.SWEEPS
    # stage2: best PSNR among those no worse in ST-LPIPS than Stage 1 only; else the best PSNR
    m = _means(
        **{"stage 1 only": (14.0, 0.20), "paper shape": (14.5, 0.19), "lr / 4": (14.9, 0.21)}
    )
    assert s["stage2"].rule.pick(s["stage2"], m) == (
        "paper shape",
        {"chosen_from_lpips_filter": True},
    )
    m["paper shape"]["stlpips_crop"] = 0.22
    assert s["stage2"].rule.pick(s["stage2"], m) == ("lr / 4", {"chosen_from_lpips_filter": False})
    # stage1: lowest ST-LPIPS within 0.25 dB of model
    m = _means(model=(15.0, 0.25), **{"transfer r2": (14.8, 0.22), "transfer r6": (14.7, 0.20)})
    assert s["stage1"].rule.pick(s["stage1"], m) == ("transfer r2", {"psnr_floor_db": 14.75})
    # noise: shared only if PSNR higher AND ST-LPIPS no worse
    m = _means(**{"per-view noise": (14.0, 0.20), "shared noise": (14.5, 0.21)})
    assert s["noise"].rule.pick(s["noise"], m)[0] == "per-view noise"
    m["shared noise"]["stlpips_crop"] = 0.20
    assert s["noise"].rule.pick(s["noise"], m)[0] == "shared noise"
    # stage2-detail: a radius only when it beats model in PSNR with ST-LPIPS no worse
    m = _means(model=(15.0, 0.20), **{"transfer r4": (15.1, 0.21), "transfer r8": (14.9, 0.19)})
    assert s["stage2-detail"].rule.pick(s["stage2-detail"], m)[0] == "model"
    m["transfer r8"]["psnr_object_db"] = 15.2
    assert s["stage2-detail"].rule.pick(s["stage2-detail"], m)[0] == "transfer r8"


def test_the_l1_rule_keeps_full_frame_and_breaks_ties_to_the_largest(ns: Any) -> None:
    spec = ns.SWEEPS["l1"]

    def row(l1: float, obj: float, full: float) -> tuple[str, dict[str, float]]:
        return f"{l1:g}", {"l1_initial": l1, "psnr_object_db": obj, "psnr_full_frame_db": full}

    m = dict(
        [row(8e-5, 19.0, 30.0), row(8e-6, 21.15, 30.0), row(0.0, 21.2, 30.0), row(2e-6, 22.0, 29.8)]
    )
    # 2e-06 is best but loses 0.2 dB of full frame; 0 and 8e-06 tie within 0.1 dB: the larger L1
    assert spec.rule.pick(spec, m)[0] == "8e-06"
