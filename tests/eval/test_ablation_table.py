"""The ablation table's arithmetic: means over scenes, the paper's orderings and their verdicts."""

from __future__ import annotations

from pipelines.experiments.ablation import FAMILIES, PAPER_PSNR, paper_claims, plan
from pipelines.experiments.tables import claims_table, csv_text, markdown_table, variant_means


def _result(scene: str, variant: str, psnr: float, status: str = "ok") -> dict:
    return {"scene": scene, "variant": variant, "status": status, "restoration": {"psnr": psnr, "ssim": 0.5},
            "wall_seconds": 10.0}  # fmt: skip


def test_claims_are_the_papers_adjacent_orderings_without_repeats():
    pairs = [(c.worse, c.better) for c in paper_claims()]
    assert len(pairs) == len(set(pairs))
    assert ("constant", "gaussian-bound") in pairs and ("tgc-start", "no-tgc") in pairs
    for c in paper_claims():
        assert PAPER_PSNR[c.worse] < PAPER_PSNR[c.better]
    assert [v.name for v in plan(["schedule", "losses"])] == ["no-tgc", "tgc-start", "full", "no-depth-corr",
                                                             "no-smooth", "no-dcp"]  # fmt: skip


def test_verdicts_with_a_noise_band():
    results = [
        _result("a", "no-tgc", 18.0), _result("b", "no-tgc", 20.0),  # mean 19.0
        _result("a", "tgc-start", 16.0), _result("b", "tgc-start", 16.5),  # mean 16.25
        _result("a", "full", 19.2), _result("b", "full", 19.0),  # mean 19.1
        _result("a", "vanilla-gs", 0.0, status="failed"),
    ]  # fmt: skip
    means = variant_means(results, ["a", "b"])
    assert means["no-tgc"]["psnr"] == 19.0 and "vanilla-gs" not in means
    _, rows = claims_table(results, ["a", "b"], ["schedule"], noise_db=0.5)
    verdict = {(r["worse"], r["better"]): r["agrees"] for r in rows}
    assert verdict == {("tgc-start", "no-tgc"): "yes", ("no-tgc", "full"): "tie"}
    _, rows = claims_table(results, ["a", "b"], ["schedule"], noise_db=0.0)
    assert {(r["worse"], r["better"]): r["agrees"] for r in rows}[("no-tgc", "full")] == "yes"
    baselines = {"hazy_input": {"a": 11.0, "b": 12.0}, "dcp_2d": {"a": 15.0}}
    md = markdown_table(results, ["a", "b"], ["schedule", "baselines"], baselines)
    assert "| no TGC | 18.00 | 20.00 | 19.00 |" in md and "| hazy input | 11.00 | 12.00 | 11.50 |" in md
    assert "| single-image DCP (2D) | 15.00 | - | 15.00 |" in md  # a scene without the baseline shows -
    assert "hazy input" not in markdown_table(results, ["a", "b"], ["schedule"], baselines)
    assert "| vanilla 3DGS | failed | - |" in md
    assert csv_text(results).count("\n") == len(results) + 1
    assert set(FAMILIES) == {"representation", "field", "schedule", "losses", "baselines"}


def test_tables_carry_the_medium_errors():
    results = [
        {**_result("a", "full", 19.0), "medium": {"t_mae": 0.08, "s_mae": 0.05}},
        {**_result("b", "full", 20.0), "medium": {"t_mae": 0.06, "s_mae": 0.03}},
        _result("a", "vanilla-gs", 9.0),  # no medium: no medium numbers
    ]
    means = variant_means(results, ["a", "b"])
    assert means["full"]["t_mae"] == 0.07 and means["full"]["s_mae"] == 0.04
    assert means["vanilla-gs"]["t_mae"] is None
    md = markdown_table(results, ["a", "b"], ["schedule", "baselines"], {})
    assert "| T MAE | S MAE |" in md and "| 19.50 | 0.500 | - | - | 0.070 | 0.040 |" in md
    assert "t_mae,s_mae" in csv_text(results).splitlines()[0]
