"""td-bench restoration: the table's arithmetic, the targets, and one tiny end-to-end sweep."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from pipelines.experiments.restoration_bench import (
    BENCHMARK,
    HOLDOUT,
    SCENES,
    Targets,
    build,
    check_targets,
    markdown,
    method_order_warning,
    scene_rows,
)


def _r(scene: str, method: str, psnr: float, **extra) -> dict:
    out = {"scene": scene, "variant": method, "status": "ok", "restoration": {"psnr": psnr, "ssim": 0.8, "lpips": 0.2},
           "baselines": {"hazy_input": {"psnr": 10.0}, "dcp_2d": {"psnr": 15.0}}}  # fmt: skip
    out.update(extra)
    return out


def test_the_set_covers_every_layout_and_hazy_preset():
    from components.synth.layouts import LAYOUTS
    from components.synth.medium import PRESETS

    assert {layout for layout, _ in SCENES} == set(LAYOUTS)
    assert {haze for _, haze in SCENES} == set(PRESETS) - {"none"}


def test_the_holdout_set_shares_no_scene_with_the_benchmark_and_is_built_at_its_own_size(
    tmp_path, monkeypatch
):
    """The out-of-sample set: other layout and haze pairs, another seed, td-synth's default size."""
    from components.synth.generate import SceneConfig
    from components.synth.layouts import LAYOUTS
    from pipelines.experiments import restoration_bench as rb

    assert not set(HOLDOUT.scenes) & set(BENCHMARK.scenes) and HOLDOUT.seed != BENCHMARK.seed
    assert {layout for layout, _ in HOLDOUT.scenes} == set(LAYOUTS) and len(set(HOLDOUT.names())) == 8
    default = SceneConfig(output_dir=tmp_path)
    assert (HOLDOUT.width, HOLDOUT.height, HOLDOUT.num_views) == (
        default.width,
        default.height,
        default.num_views,
    )
    made = []
    monkeypatch.setattr(rb, "generate_scene", made.append)
    paths = build(tmp_path, ["street-dense", "courtyard-patchy"], log=lambda _: None, scene_set=HOLDOUT)
    assert [c.output_dir.name for c in made] == ["street-dense"]  # a benchmark name is not the holdout's
    cfg = made[0]
    assert (cfg.layout, cfg.haze, cfg.seed, cfg.width, cfg.height, cfg.num_views) == (
        "street",
        "dense",
        11,
        160,
        120,
        32,
    )
    assert [p.name for p in paths] == ["street-dense", "courtyard-patchy"]  # the other: a user's own folder
    made.clear()
    build(tmp_path, ["room-uniform"], log=lambda _: None)
    assert (made[0].seed, made[0].width, made[0].num_views) == (5, 96, 24)  # the benchmark's, by default


def test_a_scene_folder_from_another_generator_or_other_settings_is_refused_not_reused(tmp_path, monkeypatch):
    """A set built before a generator change (session 45's short tracks) must not be mixed in."""
    from dataclasses import asdict

    from components.synth.generate import GENERATOR_VERSION, SceneConfig, mismatch
    from pipelines.experiments import restoration_bench as rb
    from tridehaze_plugin.errors import DataError

    made = []
    monkeypatch.setattr(rb, "generate_scene", made.append)
    folder = tmp_path / "room-uniform"
    folder.mkdir()
    (folder / "transforms.json").write_text("{}")
    cfg = SceneConfig(output_dir=folder, layout="room", haze="uniform", seed=BENCHMARK.seed,
                      num_views=BENCHMARK.num_views, width=BENCHMARK.width, height=BENCHMARK.height)  # fmt: skip
    settings = {k: (str(v) if k == "output_dir" else v) for k, v in asdict(cfg).items()}
    meta = {"generator_version": GENERATOR_VERSION, "settings": settings}
    (folder / "synth_meta.json").write_text(json.dumps(meta))
    assert mismatch(folder, cfg) is None
    assert build(tmp_path, ["room-uniform"], log=lambda _: None) == [folder] and made == []  # reused
    for change, why in ((dict(generator_version=None), "generator version 1"),
                        (dict(settings={**settings, "width": 160}), "settings differ (width)")):  # fmt: skip
        (folder / "synth_meta.json").write_text(
            json.dumps({k: v for k, v in {**meta, **change}.items() if v})
        )
        assert why in mismatch(folder, cfg)
        with pytest.raises(DataError, match="cannot be reused") as err:
            build(tmp_path, ["room-uniform"], log=lambda _: None)
        assert why in str(err.value) and str(folder) in str(err.value) and "--set-dir" in str(err.value)
    (folder / "synth_meta.json").unlink()
    assert "no readable synth_meta.json" in mismatch(folder, cfg)
    r = subprocess.run([sys.executable, "-m", "tridehaze_plugin.cli.bench", "restoration", "--set-dir", str(tmp_path),
                        "--scenes", "room-uniform", "--output-dir", str(tmp_path / "out")],
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2 and "cannot be reused" in r.stderr and "Traceback" not in r.stderr
    assert made == [] and sorted(p.name for p in folder.iterdir()) == ["transforms.json"]  # nothing touched


def test_a_scene_written_meanwhile_by_another_run_is_used_when_it_is_the_same_scene(tmp_path, monkeypatch):
    """Two td-bench arms started on a new set both generate each scene; the one that loses the
    rename uses the winner's folder (the generator is deterministic) unless it is another scene."""
    from dataclasses import asdict, replace

    from components.synth.generate import GENERATOR_VERSION
    from components.synth.writer import OutputTakenError
    from pipelines.experiments import restoration_bench as rb
    from tridehaze_plugin.errors import DataError

    def loser(cfg, width=None):
        """Another run's rename lands first; this one's staged copy is refused."""
        cfg.output_dir.mkdir()
        (cfg.output_dir / "transforms.json").write_text("{}")
        written = replace(cfg, width=width) if width else cfg
        settings = {k: (str(v) if k == "output_dir" else v) for k, v in asdict(written).items()}
        meta = {"generator_version": GENERATOR_VERSION, "settings": settings}
        (cfg.output_dir / "synth_meta.json").write_text(json.dumps(meta))
        raise OutputTakenError(
            "output folder was filled by someone else while writing", where=str(cfg.output_dir)
        )

    logged = []
    monkeypatch.setattr(rb, "generate_scene", loser)
    assert build(tmp_path, ["room-uniform"], log=logged.append) == [tmp_path / "room-uniform"]
    assert logged == ["room-uniform: written meanwhile by another run; using it"]
    monkeypatch.setattr(rb, "generate_scene", lambda cfg: loser(cfg, width=160))
    with pytest.raises(OutputTakenError):  # someone wrote another scene there: not used
        build(tmp_path, ["room-patchy"], log=logged.append)
    with pytest.raises(DataError, match="cannot be reused"):  # and a later build refuses it
        build(tmp_path, ["room-patchy"], log=logged.append)


def test_rows_average_seeds_and_targets_name_the_worst_scene():
    results = {
        42: [_r("a", "tri-dehaze", 24.0, medium={"t_mae": 0.04, "s_mae": 0.02}, observable={"psnr": 26.0, "share": 0.8}),
             _r("a", "vanilla-gs", 12.0),
             _r("a", "dcp-gs", 16.0), _r("b", "tri-dehaze", 19.0, medium={"t_mae": 0.08, "s_mae": 0.02}),
             _r("b", "vanilla-gs", 11.0), _r("b", "dcp-gs", 0.0, status="failed")],
        7: [_r("a", "tri-dehaze", 22.0, medium={"t_mae": 0.06, "s_mae": 0.02}, observable={"psnr": 24.0, "share": 0.8}),
            _r("a", "vanilla-gs", 14.0),
            _r("a", "dcp-gs", 18.0)],
    }  # fmt: skip
    rows = scene_rows(results, ["a", "b"], "tri-dehaze")
    a, b = rows
    assert (
        a["psnr"] == 23.0 and a["spread"] == 2.0 and a["seeds"] == 2 and a["per_seed"] == {42: 24.0, 7: 22.0}
    )
    assert a["vanilla-gs"] == 13.0 and a["dcp-gs"] == 17.0 and a["t_mae"] == pytest.approx(0.05)
    assert b["seeds"] == 1 and b["spread"] is None and b["dcp-gs"] is None  # the failed run is no number
    assert a["observable"] == 25.0 and a["observable_share"] == 0.8 and b["observable"] is None
    checks = {c["target"]: c for c in check_targets(rows, Targets())}
    assert (
        checks["mean restoration PSNR (dB)"]["value"] == 21.0
        and checks["mean restoration PSNR (dB)"]["met"] is False
    )
    assert checks["worst margin over vanilla-gs (dB)"]["value"] == 8.0  # min(23 - 13, 19 - 11)
    assert checks["worst margin over vanilla-gs (dB)"]["met"] is True
    assert checks["worst margin over dcp-gs (dB)"]["met"] is None  # not measured on every scene
    assert checks["worst margin over single-image DCP (dB)"]["value"] == 4.0
    assert checks["mean T MAE"]["value"] == pytest.approx(0.065) and checks["mean T MAE"]["met"] is False
    assert checks["mean S MAE"]["met"] is True
    md = markdown(rows, list(checks.values()), "tri-dehaze", [42, 7])
    assert (
        "| a | 10.00 | 15.00 | 13.00 | 17.00 | 23.00 (2.00) |" in md
        and "| +10.00 | +6.00 | +8.00 | 25.00 (80 %) |" in md
    )
    assert "| mean T MAE | 0.065 | 0.05 | no |" in md


def test_td_bench_restoration_end_to_end(tmp_path):
    from components.synth.generate import SceneConfig, generate_scene

    out = tmp_path / "out"
    # a user's own hazy scene beside the generated set (any name, any generator settings)
    generate_scene(SceneConfig(output_dir=tmp_path / "set" / "my-fog", layout="street", haze="homogeneous",
                               num_views=6, width=32, height=24, seed=3))  # fmt: skip
    args = ["--set-dir", str(tmp_path / "set"), "--output-dir", str(out), "--scenes", "room-uniform", "my-fog",
            "--seeds", "1", "2", "--max-steps", "3", "--methods", "vanilla-gs", "tri-dehaze", "--lpips", "off",
            "--train-args=--pipeline.warmup-steps 1 --pipeline.rasterizer.backend torch"]  # fmt: skip
    r = subprocess.run([sys.executable, "-m", "tridehaze_plugin.cli.bench", "restoration", *args],
                       capture_output=True, text=True, timeout=600)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    # only the named subset of the generated set is built
    assert sorted(p.name for p in (tmp_path / "set").iterdir()) == ["my-fog", "room-uniform"]
    summary = json.loads((out / "restoration.json").read_text())
    row, mine = summary["rows"]
    assert summary["scenes"] == ["room-uniform", "my-fog"] and mine["scene"] == "my-fog"
    for r_ in (row, mine):
        assert r_["seeds"] == 2 and set(r_["per_seed"]) == {"1", "2"}
        assert r_["psnr"] > 5 and r_["vanilla-gs"] > 5 and r_["dcp_2d"] > 5 and 0 <= r_["t_mae"] <= 1
    assert row["scene"] == "room-uniform" and row["observable"] > 5 and 0 < row["observable_share"] <= 1
    md = (out / "restoration.md").read_text()
    assert "| room-uniform |" in md and "| my-fog |" in md
    bad = subprocess.run([sys.executable, "-m", "tridehaze_plugin.cli.bench", "restoration", "--scenes", "moon-fog",
                          "--set-dir", str(tmp_path / "set2")], capture_output=True, text=True, timeout=120)  # fmt: skip
    assert bad.returncode == 2 and "moon-fog" in bad.stderr and "Traceback" not in bad.stderr
    assert "no dataset" in bad.stderr
    assert not (tmp_path / "set2").exists()
    # a benchmark scene's name is not a holdout scene: the error names the holdout's
    bad = subprocess.run([sys.executable, "-m", "tridehaze_plugin.cli.bench", "restoration", "--scene-set", "holdout",
                          "--scenes", "room-uniform", "--set-dir", str(tmp_path / "set3")],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert bad.returncode == 2 and "holdout set" in bad.stderr and "room-homogeneous" in bad.stderr
    assert "Traceback" not in bad.stderr and not (tmp_path / "set3").exists()


def test_a_baseline_reported_against_the_method_under_test_is_warned_about():
    """The table reports the last of --methods: a baseline there while tri-dehaze is listed too is
    almost surely a mistake, and the warning gives the order that reports tri-dehaze."""
    msg = method_order_warning(["tri-dehaze", "vanilla-gs", "dcp-gs"])
    assert msg is not None and "dcp-gs, a baseline" in msg
    assert "--methods vanilla-gs dcp-gs tri-dehaze" in msg
    assert method_order_warning(["vanilla-gs", "dcp-gs", "tri-dehaze"]) is None
    assert method_order_warning(["dcp-gs"]) is None  # a baseline alone is benchmarked on purpose
    assert method_order_warning(["vanilla-gs", "dcp-gs"]) is None
    assert "tri-dehaze-fast" in method_order_warning(["tri-dehaze-fast", "vanilla-gs"])
