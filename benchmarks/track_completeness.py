"""How complete are SfM tracks on hazy photos? Real SfM on generated scenes against td-synth's tracks.

A track lists the views in which SfM matched a point. td-synth's default tracks were complete (every
train view that sees the point unoccluded), while COLMAP on hazy photos keeps only the views where
matching succeeded. This measures, per scene, on the reconstruction ``benchmarks/seed_cloud.py``
makes (``td-process-data images --enhance clahe``, aligned to the true cameras):

- each point's track length and the number of registered views that see it (its true position
  projects inside the image and the true depth there agrees with its depth within ``VISIBLE``);
- the share of those seeing views that are in the track (completeness), overall and binned by the
  true transmittance at the point in that view and by the angle between that view's ray and the
  nearest ray of the track's other views.

The same numbers for the tracks td-synth wrote (``points3d_tracks.npy``, train views only), so the
generator's track model can be checked against what SfM does.

    python benchmarks/seed_cloud.py ... (its docstring: scenes/ and sfm/)
    python benchmarks/track_completeness.py --scenes scenes/* --work sfm --output docs/results/track_completeness
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import seed_cloud as sc  # noqa: E402

VISIBLE = 0.05
"""A view sees a point when the true depth at its projection is within this share of its depth
(SfM depth errors are 1-8 % in the median, docs/results/seed_cloud.md)."""
T_EDGES = (0.0, 0.2, 0.4, 0.6, 0.8, 1.01)
ANGLE_EDGES = (0.0, 5.0, 10.0, 20.0, 40.0, 180.0)


def centres(views: dict[str, dict]) -> dict[str, np.ndarray]:
    return {n: np.linalg.inv(v["w2c"])[:3, 3] for n, v in views.items()}


def seeing(x: np.ndarray, names: list[str], views: dict[str, dict]) -> dict[str, float]:
    """Views of ``names`` that see world point ``x`` [3], each with the true T there."""
    out = {}
    for n in names:
        o = sc.observe(views[n], x[None])
        if (
            o["inside"][0]
            and o["z_true"][0] > 0
            and abs(o["z"][0] - o["z_true"][0]) < VISIBLE * o["z_true"][0]
        ):
            out[n] = float(o["T"][0])
    return out


def pair_rows(x: np.ndarray, track: set[str], names: list[str], views: dict, cen: dict) -> list[tuple]:
    """(in track, T, angle to the nearest other track view in degrees) per view that sees ``x``;
    empty when under half of the track's views see the point (an outlier). A track view whose depth
    misses the tolerance is left out of both counts."""
    see = seeing(x, names, views)
    if not track or 2 * len(track & set(see)) < len(track):
        return []
    rays = {n: (x - cen[n]) / np.linalg.norm(x - cen[n]) for n in set(see) | track}
    rows = []
    for n, t in see.items():
        others = [m for m in track if m != n]
        if not others:
            continue
        ang = min(np.degrees(np.arccos(np.clip(rays[n] @ rays[m], -1, 1))) for m in others)
        rows.append((n in track, t, ang))
    return rows


def sfm_rows(model: Path, views: dict[str, dict]) -> tuple[list, list[int]]:
    rec, s, R, t = sc.load_aligned(model, views)  # raises on a failed or wrong reconstruction
    names = [im.name for im in rec.images.values()]
    cen = centres(views)
    rows, lengths = [], []
    print(f"  sfm: {len(rec.points3D)} points, {len(rec.images)} views registered", flush=True)
    for p in rec.points3D.values():
        x = s * R @ np.asarray(p.xyz) + t
        track = {rec.images[el.image_id].name for el in p.track.elements}
        r = pair_rows(x, track, names, views, cen)
        if r:
            rows += r
            lengths.append(len(track))
    return rows, lengths


def model_rows(scene: Path, views: dict[str, dict]) -> tuple[list, list[int]]:
    """The same rows for td-synth's own cloud and tracks (its points carry their noise; a point whose
    noisy position no track view sees is left out, as for SfM)."""
    tf = json.loads((scene / "transforms.json").read_text())
    xyz, _ = sc.read_ply_points(scene / tf["ply_file_path"])
    pairs = np.load(scene / tf["point_tracks_file_path"])
    frames = [Path(f["file_path"]).name for f in tf["frames"]]  # the pairs' view index is the frame's
    names = [Path(f).name for f in tf["train_filenames"]]
    cen = centres(views)
    tracks: dict[int, set[str]] = {}
    for p, j in pairs:
        tracks.setdefault(int(p), set()).add(frames[int(j)])
    rows, lengths = [], []
    for p, track in tracks.items():
        r = pair_rows(xyz[p], track, names, views, cen)
        if r:
            rows += r
            lengths.append(len(track))
    return rows, lengths


def summarise(rows: list, lengths: list[int]) -> dict:
    a = np.asarray(rows, np.float64).reshape(-1, 3)
    inc, T, ang = a[:, 0] > 0.5, a[:, 1], a[:, 2]
    seen_per_point = len(a) / max(len(lengths), 1)

    def binned(v, edges):
        return {f"{lo:g}-{min(hi, 180 if edges is ANGLE_EDGES else 1):g}":
                {"pairs": int(m.sum()), "in_track": float(inc[m].mean()) if m.any() else None}
                for lo, hi in zip(edges[:-1], edges[1:], strict=True) for m in [(v >= lo) & (v < hi)]}  # fmt: skip

    return {
        "points": len(lengths),
        "track_length_median": float(np.median(lengths)) if lengths else None,
        "seeing_views_mean": seen_per_point,
        "completeness": float(inc.mean()) if len(a) else None,
        "by_T": binned(T, T_EDGES),
        "by_angle": binned(ang, ANGLE_EDGES),
    }


def markdown(results: dict) -> str:
    tb = [f"{lo:g}-{min(hi, 1):g}" for lo, hi in zip(T_EDGES[:-1], T_EDGES[1:], strict=True)]
    ab = [f"{lo:g}-{min(hi, 180):g}" for lo, hi in zip(ANGLE_EDGES[:-1], ANGLE_EDGES[1:], strict=True)]
    head = ["scene", "tracks", "points", "length (median)", "seeing views (mean)", "complete",
            *(f"T {b}" for b in tb), *(f"{b} deg" for b in ab)]  # fmt: skip
    lines = [
        "# Track completeness: real SfM on generated hazy views against td-synth's tracks",
        "",
        "Written by `python benchmarks/track_completeness.py` (command in its docstring). `sfm`: the "
        "reconstruction of `benchmarks/seed_cloud.py`; `model`: the tracks td-synth wrote. "
        "Completeness: share of the (point, view) pairs where the view sees the point that are in its "
        "track; binned by the true T at the point in that view and by the angle to the nearest other "
        "track view's ray. Discussion: docs/synth.md.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    fmt = lambda d: "-" if d["in_track"] is None else f"{d['in_track']:.2f} ({d['pairs']})"  # noqa: E731
    for scene, entry in results.items():
        for kind, s in entry.items():
            if "error" in s:
                lines.append(f"| {scene} | {kind} | failed: {s['error']} |")
                continue
            lines.append(
                f"| {scene} | {kind} | {s['points']} | {s['track_length_median']:.0f} | "
                f"{s['seeing_views_mean']:.1f} | {s['completeness']:.2f} | "
                + " | ".join(fmt(s["by_T"][b]) for b in tb)
                + " | "
                + " | ".join(fmt(s["by_angle"][b]) for b in ab)
                + " |"
            )
    return "\n".join(lines) + "\n\nBinned cells: share in track (pairs).\n"


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    colours = {"sfm": "tab:red", "model": "tab:blue"}
    for entry in results.values():
        for kind, s in entry.items():
            if "error" in s:
                continue
            for ax, key, edges in ((axes[0], "by_T", T_EDGES), (axes[1], "by_angle", ANGLE_EDGES)):
                vals = [np.nan if d["in_track"] is None else d["in_track"] for d in s[key].values()]
                ax.plot(range(len(edges) - 1), vals, marker="o", color=colours.get(kind, "tab:green"),
                        alpha=0.6, label=kind)  # fmt: skip
    axes[0].set_xticks(range(len(T_EDGES) - 1), list(next(iter(results.values()))["model"]["by_T"]))
    axes[0].set_xlabel("true T at the point in the view")
    axes[1].set_xticks(range(len(ANGLE_EDGES) - 1), list(next(iter(results.values()))["model"]["by_angle"]))
    axes[1].set_xlabel("angle to the nearest other track view (deg)")
    for ax in axes:
        ax.set_ylabel("share of seeing views in the track")
        ax.set_ylim(0, 1.05)
    sc.save_figure(fig, axes, path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="+", type=Path, required=True)
    ap.add_argument("--work", type=Path, required=True, help="seed_cloud.py's SfM folder (reused, or made)")
    ap.add_argument("--output", type=Path, required=True, help="path stem of the .json / .md / .png written")
    ap.add_argument("--enhance", default="clahe")
    args = ap.parse_args()
    results = {}
    for scene in args.scenes:
        views = sc.true_views(scene)
        entry = {}
        try:
            model = sc.run_sfm(scene, args.work, args.enhance)
            entry["sfm"] = summarise(*sfm_rows(model, views))
        except Exception as e:  # noqa: BLE001 (a failed reconstruction is a row, not a crash)
            entry["sfm"] = {"error": str(e).splitlines()[0][:200]}
        entry["model"] = summarise(*model_rows(scene, views))
        results[scene.name] = entry
        print(scene.name, json.dumps({k: {kk: vv for kk, vv in v.items() if not kk.startswith("by_")}
                                      for k, v in entry.items()}), flush=True)  # fmt: skip
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.with_suffix(".json").write_text(json.dumps(results, indent=2) + "\n")
    md = markdown(results)
    args.output.with_suffix(".md").write_text(md)
    plot(results, args.output.with_suffix(".png"))
    print(md)


if __name__ == "__main__":
    main()
