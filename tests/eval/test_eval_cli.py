"""td-eval and td-ablate end to end on tiny runs: files, keys, images, errors, resumption."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from tridehaze_plugin.cli.eval import main as eval_main

ROOT = Path(__file__).resolve().parents[2]


def _cli(module: str, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", module, *args], capture_output=True, text=True, cwd=ROOT,
        env={**os.environ, "OMP_NUM_THREADS": "1", **(env or {})}, timeout=300,
    )  # fmt: skip


def test_td_eval_writes_json_markdown_and_side_by_side(tri_run, need_lpips, tmp_path):
    out = tmp_path / "res" / "tri.json"
    eval_main(["--load-config", str(tri_run), "--output-path", str(out)])
    report = json.loads(out.read_text())
    for protocol in ("restoration", "reconstruction"):
        assert set(report[protocol]) >= {"psnr", "ssim", "lpips", "views"}
        assert 0 < report[protocol]["lpips"] < 1 and 5 < report[protocol]["psnr"] < 60
    assert report["reconstruction"]["composite"] is True and report["binned"]["source"] == "model"
    assert report["lpips"]["available"] is True and report["step"] == 6
    assert len(report["per_view"]) == report["views"] == 2
    md = out.with_suffix(".md").read_text()
    assert "| restoration |" in md and "| low (T <= 0.4) |" in md
    images = sorted((tmp_path / "res" / "tri_images").glob("*.png"))
    views = [p for p in images if not p.stem.endswith("_medium")]
    assert len(views) == 2 and [p.stem for p in images if p not in views] == [
        f"{p.stem}_medium" for p in views
    ]
    img = cv2.imread(str(views[0]))
    assert img.shape == (36 + 16, 4 * 48, 3)  # caption band; hazy | clean | reference | transmittance
    assert cv2.imread(str(images[1])).shape == img.shape  # model T | true T | model S | true S
    med = report["medium"]  # the generated scene carries its true T and S
    assert med["views"] == 2 and 0 <= med["t_mae"] <= 1 and 0 <= med["s_mae"] <= 1
    assert med["true_inverted_psnr"] > 30 and "Medium recovery" in md and "| T MAE |" in md
    assert 0 <= med["t_mae_true_depth"] <= 1 and 0 <= med["s_mae_true_depth"] <= 1  # tri-dehaze marches
    dcp = report["baselines"]["dcp_2d"]  # the 2D baseline on the same views, in the JSON and the table
    assert (
        dcp["views"] == 2
        and 0 < dcp["lpips"] < 1
        and f"| baseline: single-image DCP (2D) | {dcp['psnr']:.2f} |" in md
    )


def test_td_eval_default_path_and_plain_method(plain_run):
    eval_main(["--load-config", str(plain_run), "--lpips", "off", "--no-images"])
    report = json.loads((plain_run.parent / "eval" / "test.json").read_text())
    assert report["reconstruction"]["composite"] is False  # its plain render against the hazy input
    assert report["binned"]["source"] == "reference" and report["restoration"]["lpips"] is None
    assert "turned off" in report["lpips"]["reason"]
    assert not (plain_run.parent / "eval" / "test_images").exists()


@pytest.mark.parametrize(
    ("args", "env", "expect"),
    [
        (["--output-path", "x.txt"], {}, "--output-path must end in .json"),
        (["--lpips", "on"], {"TRIDEHAZE_LPIPS_WEIGHTS": "/nonexistent/alexnet.ckpt"}, "LPIPS is unavailable"),
        (["--split", "nope"], {}, "nope"),
    ],
)
def test_td_eval_bad_input_is_one_line_exit_2(tri_run, args, env, expect):
    before = (
        sorted(p.name for p in (tri_run.parent / "eval").glob("*"))
        if (tri_run.parent / "eval").exists()
        else []
    )
    r = _cli("tridehaze_plugin.cli.eval", "--load-config", str(tri_run), *args, env=env)
    assert r.returncode == 2, r.stderr
    assert expect in r.stderr and "Traceback" not in r.stderr
    after = (
        sorted(p.name for p in (tri_run.parent / "eval").glob("*"))
        if (tri_run.parent / "eval").exists()
        else []
    )
    assert after == before  # nothing written


def test_td_eval_missing_run_is_clear(tmp_path):
    r = _cli("tridehaze_plugin.cli.eval", "--load-config", str(tmp_path / "nope" / "config.yml"))
    assert r.returncode == 2 and "Traceback" not in r.stderr and "config" in r.stderr.lower()


def test_td_ablate_runs_resumes_and_tabulates(eval_scene, tmp_path):
    out = tmp_path / "abl"
    train_args = "--pipeline.warmup-steps 2 --pipeline.model.sh-degree 0 --pipeline.rasterizer.backend torch"
    args = ["--scenes", str(eval_scene), "--max-steps", "4", "--output-dir", str(out), "--families", "schedule",
            "--jobs", "2", "--lpips", "off", f"--train-args={train_args}"]  # fmt: skip
    r = _cli("tridehaze_plugin.cli.ablate", *args)
    assert r.returncode == 0, r.stdout + r.stderr
    rows = list(csv.DictReader((out / "ablation.csv").open()))
    assert sorted(row["variant"] for row in rows) == ["full", "no-tgc", "tgc-start"]
    assert all(row["status"] == "ok" and float(row["restoration_psnr"]) > 5 for row in rows)
    md = (out / "ablation.md").read_text()
    assert "### schedule" in md and "TGC from the start" in md and "tgc-start < no-tgc" in md
    assert (out / "ablation.png").stat().st_size > 1000
    summary = json.loads((out / "ablation.json").read_text())
    assert set(summary["baseline_psnr"]) == {"hazy_input", "dcp_2d"} and "| single-image DCP (2D) |" not in md
    claims = summary["claims"]
    assert {c["family"] for c in claims} == {"schedule"} and all(
        c["agrees"] in ("yes", "no", "tie") for c in claims
    )

    # a finished run is skipped; a run with a checkpoint but no result is resumed, not restarted
    result = out / "results" / eval_scene.name / "no-tgc.json"
    result.unlink()
    r = _cli("tridehaze_plugin.cli.ablate", *args)
    assert r.returncode == 0, r.stdout + r.stderr
    assert r.stdout.count("finished earlier") == 2 and result.is_file()
    log = (out / "logs" / f"{eval_scene.name}__no-tgc.log").read_text()
    assert "--resume" in log

    # other settings (more steps) invalidate the stored results
    r = _cli("tridehaze_plugin.cli.ablate", *[a if a != "4" else "5" for a in args], "--dry-run")
    assert r.returncode == 0 and r.stdout.count("to run") == 3


def test_td_ablate_bad_input(tmp_path):
    r = _cli("tridehaze_plugin.cli.ablate", "--scenes", str(tmp_path / "missing"))
    assert r.returncode == 2 and "scene folder not found" in r.stderr and "Traceback" not in r.stderr
    (tmp_path / "a" / "s").mkdir(parents=True)
    (tmp_path / "b" / "s").mkdir(parents=True)
    r = _cli("tridehaze_plugin.cli.ablate", "--scenes", str(tmp_path / "a" / "s"), str(tmp_path / "b" / "s"))
    assert r.returncode == 2 and "must differ" in r.stderr


def test_resume_keeps_the_variants_own_step_count(tmp_path):
    """A variant with its own step budget (the probe bench's fast preset: 1000 of the runner's
    3000) resumes to its own budget, not the runner's."""
    from pipelines.engine.run_config import write_text_atomic
    from pipelines.experiments.ablation import Variant
    from pipelines.experiments.runner import AblationRunner, Job, RunnerOptions

    runner = AblationRunner(RunnerOptions(output_dir=tmp_path, max_steps=3000))
    job = Job(tmp_path / "scene", Variant("fast", "tri-dehaze-fast", max_steps=1000))
    rd = runner.run_dir(job)
    (rd / "checkpoints").mkdir(parents=True)
    (rd / "checkpoints" / "step-0000250.ckpt").write_bytes(b"x")
    runner.state_path(job).parent.mkdir(parents=True)
    write_text_atomic(runner.state_path(job), json.dumps(runner.signature(job)))
    cmd = runner._train_command(job, rd)
    assert "--resume" in cmd and cmd[cmd.index("--max-steps") + 1] == "1000", cmd
    # other settings: the folder is not resumed but restarted, with the variant's budget
    write_text_atomic(runner.state_path(job), json.dumps({"other": 1}))
    cmd = runner._train_command(job, rd)
    assert "--resume" not in cmd and not rd.exists() and cmd[cmd.index("--max-steps") + 1] == "1000"


def test_extra_arguments_name_each_runs_scene_and_seed(tmp_path):
    """``{scene}`` and ``{seed}`` in the extra td-train arguments become each run's own, in the
    command and in the signature that decides reuse (two scenes' runs differ)."""
    from pipelines.experiments.ablation import Variant
    from pipelines.experiments.runner import AblationRunner, Job, RunnerOptions

    extra = ("--pipeline.medium-from", "base/seed{seed}/runs/{scene}/last.ckpt")
    runner = AblationRunner(RunnerOptions(output_dir=tmp_path, max_steps=100, seed=7, extra=extra))
    a, b = (Job(tmp_path / name, Variant("v", "tri-dehaze")) for name in ("street", "room"))
    cmd = runner._train_command(a, runner.run_dir(a))
    assert cmd[-2:] == ["--pipeline.medium-from", "base/seed7/runs/street/last.ckpt"], cmd
    assert runner.signature(a)["extra"][1] == "base/seed7/runs/street/last.ckpt"
    assert runner.signature(a)["extra"] != runner.signature(b)["extra"]
    plain = AblationRunner(RunnerOptions(output_dir=tmp_path, max_steps=100, extra=("--x", "1")))
    assert plain.signature(a)["extra"] == ["--x", "1"]  # without placeholders: as given


@pytest.mark.parametrize("flag", ["--seed", "--max-steps", "--threads", "--seed=7"])
def test_a_variant_cannot_set_a_flag_the_runner_overrules(flag, tmp_path):
    """A variant's ``--seed 7`` used to be overruled silently by the runner's own ``--seed 42``
    (two 'seeds' that were one run)."""
    from pipelines.experiments.ablation import Variant
    from pipelines.experiments.runner import Job

    with pytest.raises(ValueError, match=f"{flag.split('=')[0]} in its overrides would be overruled"):
        Job(tmp_path, Variant("s7", "tri-dehaze", (flag, "7") if "=" not in flag else (flag,)))
    Job(tmp_path, Variant("ok", "tri-dehaze", ("--pipeline.freeze-fraction", "0.4")))


def test_runs_of_other_code_are_neither_resumed_nor_reused(tmp_path, monkeypatch):
    """A stopped run resumed after a code change used to finish under the new code from the old
    code's checkpoint; the source fingerprint in the signature makes it start afresh, and a stored
    result of the same settings shows as ``other code`` in a dry run."""
    from pipelines.engine.run_config import write_text_atomic
    from pipelines.experiments import runner as runner_mod
    from pipelines.experiments.ablation import Variant

    runner = runner_mod.AblationRunner(runner_mod.RunnerOptions(output_dir=tmp_path, max_steps=100))
    job = runner_mod.Job(tmp_path / "scene", Variant("v", "tri-dehaze"))
    rd = runner.run_dir(job)
    (rd / "checkpoints").mkdir(parents=True)
    (rd / "checkpoints" / "step-0000025.ckpt").write_bytes(b"x")
    runner.state_path(job).parent.mkdir(parents=True)
    write_text_atomic(runner.state_path(job), json.dumps(runner.signature(job)))
    runner.result_path(job).parent.mkdir(parents=True)
    write_text_atomic(
        runner.result_path(job), json.dumps({"status": "ok", "signature": runner.signature(job)})
    )
    assert runner.state(job) == "done" and "--resume" in runner._train_command(job, rd)

    monkeypatch.setattr(runner_mod, "code_fingerprint", lambda: "another-tree")
    assert runner.finished(job) is None and runner.state(job) == "other code"
    cmd = runner._train_command(job, rd)
    assert "--resume" not in cmd and not rd.exists()
    write_text_atomic(runner.result_path(job), json.dumps({"status": "ok", "signature": {"seed": 1}}))
    assert runner.state(job) == "to run"


def test_the_source_fingerprint_follows_the_code_not_the_docs(tmp_path):
    from pipelines.experiments.code_version import code_fingerprint, source_fingerprint

    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "k.cpp").write_text("int f();\n")
    first = source_fingerprint([pkg])
    (pkg / "notes.md").write_text("docs\n")
    assert source_fingerprint([pkg]) == first
    (pkg / "sub" / "k.cpp").write_text("int f(int);\n")
    changed = source_fingerprint([pkg])
    assert changed != first
    (pkg / "b.py").write_text("")
    assert source_fingerprint([pkg]) not in (first, changed)
    assert len(code_fingerprint()) == 16 and code_fingerprint() == code_fingerprint()


def test_a_result_carries_the_code_its_training_started_with(tmp_path, monkeypatch):
    """An edit of the code while a sweep runs: the run started before it is stored under the old
    code's fingerprint (so the next sweep runs it again), a run started after it under the new."""
    import threading

    from pipelines.engine.run_config import write_text_atomic
    from pipelines.experiments import runner as runner_mod
    from pipelines.experiments.ablation import Variant

    runner = runner_mod.AblationRunner(runner_mod.RunnerOptions(output_dir=tmp_path, max_steps=100))
    runner.cpu_seconds[threading.get_ident()] = 0.0
    job = runner_mod.Job(tmp_path / "scene", Variant("v", "tri-dehaze"))
    rd = runner.run_dir(job)
    monkeypatch.setattr(runner_mod, "code_fingerprint", lambda: "tree-a")
    runner._train_command(job, rd)  # starts afresh: the state holds tree-a
    monkeypatch.setattr(runner_mod, "code_fingerprint", lambda: "tree-b")  # the code edited meanwhile
    result = runner._result(job, rd, {}, 1.0, 1.0, 0.0)
    assert result["signature"]["code"] == "tree-a" and runner.signature(job)["code"] == "tree-b"
    write_text_atomic(runner.result_path(job), json.dumps(result))
    assert runner.finished(job) is None and runner.state(job) == "other code"
    runner._train_command(job, rd)  # a fresh start under tree-b
    assert runner._result(job, rd, {}, 1.0, 1.0, 0.0)["signature"]["code"] == "tree-b"
