"""Sweeps on a real two-node Ray cluster (two ``ray start`` processes on loopback addresses): a
two-scene ablation whose second node loses its worker mid-run, retried, with a complete table;
a rerun skips every finished run; the trade-off grid on an embedded Ray writes in place."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.cluster.ray_cluster import NODE_MARK, LocalRayCluster, environ_of, processes_with
from tests.export.tiny_run import make_scene

try:
    import ray  # noqa: F401
except ImportError:  # a failure in CI (make test installs the cluster extra), a skip elsewhere
    if os.environ.get("CI"):
        pytest.fail("Ray missing in CI: `make test` must install the cluster extra", pytrace=False)
    pytest.skip("the cluster extra is not installed (pip install -e '.[cluster]')", allow_module_level=True)

pytestmark = pytest.mark.xdist_group("ray")
"""One xdist worker runs these in turn (``--dist loadgroup``): Ray's per-node default ports (client
server, agents) would clash between two clusters started at once on one machine."""

TINY = ("--pipeline.warmup-steps 3 --pipeline.freeze-step 3 --pipeline.medium-hold-fraction 0 "
        "--pipeline.rasterizer.backend torch --pipeline.model.sh-degree 1")  # fmt: skip


@pytest.fixture(scope="module")
def scenes(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("ray_scenes")
    return [make_scene(root / name, width=40, height=30) for name in ("sA", "sB")]


def _gcs_peers(port: int) -> tuple[int, list[str]]:
    """How many TCP connections to the head's GCS port are established, and the remote ends of
    those that are not loopback ones."""
    seen, bad = 0, []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            local, remote, state = f[1], f[2], f[3]
            if state != "01" or int(local.rsplit(":", 1)[1], 16) != port:
                continue
            seen += 1
            host = remote.rsplit(":", 1)[0]
            # IPv4: one little-endian word, 127.x.x.x ends in 7F; IPv6: four words, ::1 or ::ffff:127.x.x.x
            v6_loop = host == "0" * 24 + "01000000" or (
                host[:24] == "0" * 16 + "FFFF0000" and host.endswith("7F")
            )
            loop = host.endswith("7F") if len(host) == 8 else v6_loop
            if not loop:
                bad.append(host)
    return seen, bad


class _KillWorkerOnSecondNode(threading.Thread):
    """Waits for a td-train child running on the second node and kills its Ray worker (SIGKILL)."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.killed: dict[str, str] = {}
        self.stop = threading.Event()

    def run(self) -> None:
        while not self.stop.is_set():
            for pid in processes_with("tridehaze_plugin.cli.train"):
                if environ_of(pid).get(NODE_MARK) != "second":
                    continue
                try:
                    cmd = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
                    ppid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
                    parent = Path(f"/proc/{ppid}/cmdline").read_bytes()
                except (OSError, ValueError):
                    continue
                if not parent.startswith(b"ray::"):
                    continue
                args = [a.decode() for a in cmd]
                time.sleep(1.0)  # mid-run: past start-up, before the end
                if not _alive(pid):  # it ended meanwhile (a slow, busy machine): wait for the next run
                    continue
                os.kill(ppid, signal.SIGKILL)
                self.killed = {"variant": args[args.index("--timestamp") + 1],
                               "scene": Path(args[args.index("--data") + 1]).name, "worker": parent.split(b"\0")[0].decode()}  # fmt: skip
                return
            time.sleep(0.05)


def _alive(pid: int) -> bool:
    """The process exists and is not a zombie (it has not finished its run)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _ablate(out: Path, scenes: list[Path], env: dict[str, str], *extra: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "tridehaze_plugin.cli.ablate", "--scenes", *map(str, scenes), "--max-steps", "40",
           "--output-dir", str(out), "--families", "schedule", "--lpips", "off", f"--train-args={TINY}", *extra]  # fmt: skip
    return subprocess.run(cmd, capture_output=True, text=True, timeout=900, env=env)


def test_two_node_ablation_survives_a_killed_worker(scenes, tmp_path):
    out = tmp_path / "ablation"
    with LocalRayCluster(cpus_per_node=1) as cluster:
        killer = _KillWorkerOnSecondNode()
        killer.start()
        env = {**cluster.env, "TD_SWEEP_SCRATCH": str(tmp_path / "scratch")}
        try:
            r = _ablate(out, scenes, env, "--executor", "ray", "--ray-address", cluster.address,
                        "--ray-shared-fs", "no")  # fmt: skip
        finally:
            killer.stop.set()
            killer.join(5)
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
        seen, foreign = _gcs_peers(cluster.port)
        assert seen >= 2 and foreign == [], (seen, foreign)  # the second node's raylet is connected
        started_here = cluster.pids()
        assert started_here, "the cluster's processes should still be running before teardown"
    assert cluster.pids() == [], "teardown must stop every process the test started"
    assert processes_with(str(out)) == []  # no td-train / td-eval left behind

    # the worker was killed mid-run, and its run was retried and finished
    assert killer.killed, "no td-train ran on the second node"
    rows = list(csv.DictReader((out / "ablation.csv").open()))
    assert sorted((row["scene"], row["variant"]) for row in rows) == sorted(
        (s.name, v) for s in scenes for v in ("full", "no-tgc", "tgc-start"))  # fmt: skip
    assert all(row["status"] == "ok" for row in rows)
    results = {
        (d["scene"], d["variant"]): d for d in json.loads((out / "ablation.json").read_text())["results"]
    }
    victim = results[(killer.killed["scene"], killer.killed["variant"])]
    assert victim["attempts"] >= 2, victim
    assert f"retried: {killer.killed['scene']} / {killer.killed['variant']}" in r.stdout
    # both nodes ran runs, every node on a loopback address
    nodes = {d["node"] for d in results.values()}
    assert nodes == {"127.0.0.2", "127.0.0.3"}, nodes
    # without a shared file system the run folders came back (no checkpoints), configs naming the head's scene
    for (scene, variant), d in results.items():
        rd = Path(d["run"])
        assert rd == out / "runs" / scene / "tri-dehaze" / variant and (rd / "eval" / "test.json").is_file()
        assert not (rd / "checkpoints").exists()
        assert (out / "logs" / f"{scene}__{variant}.log").read_text().count("tridehaze_plugin.cli.eval") >= 1
    assert "done 6 / running 0 / failed 0 of 6" in r.stderr  # the live progress line

    # a rerun skips every finished run without needing a cluster
    r2 = _ablate(out, scenes, {**os.environ}, "--executor", "ray", "--ray-address", "127.0.0.2:1")
    assert r2.returncode == 0, r2.stderr
    assert r2.stdout.count("finished earlier") == 6


def test_tradeoff_on_an_embedded_ray_writes_in_place(scenes, tmp_path):
    out = tmp_path / "tradeoff"
    cmd = [sys.executable, "-m", "tridehaze_plugin.cli.bench", "tradeoff", "--scenes", str(scenes[0]),
           "--output-dir", str(out), "--knobs", "samples=4", "--combos", "--base-steps", "20", "--lpips", "off",
           "--jobs", "2", f"--train-args={TINY}", "--executor", "ray", "--storage-path", (tmp_path / "store").as_uri()]  # fmt: skip
    r = subprocess.run(
        cmd, capture_output=True, text=True, timeout=600, env={**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    )
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    data = json.loads((out / "tradeoff.json").read_text())
    assert sorted(row["name"] for row in data["rows"]) == ["base", "samples=4"]
    for res in data["results"]:
        assert res["status"] == "ok" and res["node"] == "127.0.0.1"  # the embedded Ray stays on loopback
        # shared file system (same machine): the run wrote in place, checkpoints and all, and a copy
        # without checkpoints went to the storage URI
        local = out / "runs" / scenes[0].name / "tri-dehaze" / res["variant"]
        assert (local / "checkpoints").is_dir()
        assert res["run"] == f"{(tmp_path / 'store').as_uri()}/{scenes[0].name}/tri-dehaze/{res['variant']}"
        assert (
            tmp_path / "store" / scenes[0].name / "tri-dehaze" / res["variant"] / "eval" / "test.json"
        ).is_file()
