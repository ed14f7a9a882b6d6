"""Exact k-nearest-neighbour distances for seed clouds, used to size the initial Gaussians.

Small clouds use chunked brute force (``torch.cdist``). Large ones use a uniform voxel grid:
each query looks at the 3x3x3 cells around it, which is exact whenever the k-th distance found
is below the cell size; the remaining (isolated) queries retry on a 4x coarser grid and finally
fall back to brute force. Memory stays bounded by ``max_elems`` in every path.
"""

from __future__ import annotations

import torch
from torch import Tensor

BRUTE_FORCE_MAX_POINTS = 8192
"""Up to this many points brute force is fast enough (M^2 distances)."""


def knn_distances(points: Tensor, k: int = 3, max_elems: int = 1 << 24) -> Tensor:
    """Distances [M, k] from each point to its k nearest *other* points, ascending.

    With fewer than ``k + 1`` points the farthest available neighbour is repeated.
    """
    m = points.shape[0]
    if k <= 0 or m <= 1:
        return points.new_zeros(m, max(k, 0))
    pts = points - points.mean(dim=0)  # centred: better conditioned distances
    k_eff = min(k, m - 1)
    everyone = torch.arange(m, device=points.device)
    if m <= BRUTE_FORCE_MAX_POINTS:
        dist = _brute_force(pts, everyone, k_eff, max_elems)
    else:
        dist = torch.full((m, k_eff), float("inf"), dtype=pts.dtype, device=pts.device)
        todo = everyone
        h = _cell_size(pts)
        size = float((pts.max(0).values - pts.min(0).values).max())
        while todo.numel() > 0 and h < size:
            d = _grid_query(pts, todo, h, k_eff, max_elems)  # [T, k]
            exact = d[:, -1] < h * (1.0 - 1e-6)  # every point within h is in the 27 cells
            dist[todo[exact]] = d[exact]
            todo = todo[~exact]
            h = h * 4.0  # isolated points: retry on a coarser grid
        if todo.numel() > 0:
            dist[todo] = _brute_force(pts, todo, k_eff, max_elems)
    if k_eff < k:
        dist = torch.cat([dist, dist[:, -1:].expand(m, k - k_eff)], dim=1)
    return dist


def _brute_force(pts: Tensor, queries: Tensor, k: int, max_elems: int) -> Tensor:
    """k nearest other points of ``pts[queries]`` by chunked cdist, then exact recomputation."""
    m = pts.shape[0]
    n_cand = min(k + 4, m)  # spares absorb the rounding of cdist's matmul form
    rows = max(1, max_elems // m)
    out = []
    for s in range(0, queries.numel(), rows):
        qi = queries[s : s + rows]
        q = pts[qi]  # [R, 3]
        d = torch.cdist(q, pts)  # [R, M]
        d[torch.arange(qi.numel(), device=pts.device), qi] = float("inf")  # not itself
        cand = torch.topk(d, n_cand, dim=1, largest=False).indices  # [R, n_cand]
        exact = (pts[cand] - q[:, None, :]).norm(dim=-1).masked_fill(cand == qi[:, None], float("inf"))
        out.append(torch.topk(exact, k, dim=1, largest=False).values)
    return torch.cat(out)


def _cell_size(pts: Tensor, target: float = 6.0) -> float:
    """Cell edge giving about ``target`` points per point's cell (point-weighted, so clusters count)."""
    extent = (pts.max(0).values - pts.min(0).values).clamp_min(1e-12)
    h = float((extent.prod() / pts.shape[0] * target) ** (1.0 / 3.0))
    h = max(h, float(extent.max()) * 1e-6)
    for _ in range(8):
        _, counts = torch.unique(_cell_keys(pts, h)[0], return_counts=True)
        occupancy = float((counts.double() ** 2).sum() / pts.shape[0])
        if target / 2 <= occupancy <= target * 2:
            break
        h *= min(4.0, max(0.25, (target / occupancy) ** 0.4))
    return h


def _cell_keys(pts: Tensor, h: float) -> tuple[Tensor, Tensor]:
    """Scalar cell key [M] per point and the grid dims [3]; cells start at 1 so neighbours stay >= 0."""
    cells = torch.floor((pts - pts.min(0).values) / h).long() + 1  # [M, 3]
    dims = cells.max(0).values + 2  # [3]
    return (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2], dims


def _grid_query(pts: Tensor, queries: Tensor, h: float, k: int, max_elems: int) -> Tensor:
    """k smallest distances [T, k] from ``pts[queries]`` to other points in the 27 surrounding cells.

    Rows are padded with inf when fewer than k candidates exist.
    """
    device = pts.device
    budget = max(1, max_elems // 8)  # candidates carry ~8 int64/float temporaries each
    keys, dims = _cell_keys(pts, h)  # [M], [3]
    keys_sorted, order = torch.sort(keys)
    ucell, counts = torch.unique_consecutive(keys_sorted, return_counts=True)
    starts = torch.cumsum(counts, 0) - counts
    r = torch.arange(-1, 2, device=device)
    offs = ((r[:, None, None] * dims[1] + r[None, :, None]) * dims[2] + r[None, None, :]).reshape(-1)  # [27]

    out = []
    s = 0
    while s < queries.numel():
        qi = queries[s : s + max(1, budget // 64)]
        nb = keys[qi][:, None] + offs[None, :]  # [Q, 27] neighbour cell keys
        pos = torch.searchsorted(ucell, nb).clamp_max(ucell.numel() - 1)
        cnt = torch.where(ucell[pos] == nb, counts[pos], torch.zeros_like(pos))  # [Q, 27]
        per_q = cnt.sum(1)  # [Q]
        # the padded [rows, longest row] matrix below must stay within the budget
        rows = torch.arange(1, per_q.numel() + 1, device=device)
        fits = rows * torch.cummax(per_q.clamp_min(k), 0).values <= budget
        q_take = max(1, int(fits.sum()))
        qi, pos, cnt, per_q = qi[:q_take], pos[:q_take], cnt[:q_take], per_q[:q_take]
        flat_cnt = cnt.reshape(-1)
        total = int(flat_cnt.sum())
        rep = torch.repeat_interleave(
            torch.arange(flat_cnt.numel(), device=device), flat_cnt, output_size=total
        )
        local = torch.arange(total, device=device) - (torch.cumsum(flat_cnt, 0) - flat_cnt)[rep]
        cand = order[starts[pos.reshape(-1)[rep]] + local]  # [P] candidate point ids
        row = rep // 27  # [P] query row
        d = (pts[cand] - pts[qi[row]]).norm(dim=-1).masked_fill(cand == qi[row], float("inf"))
        # pad per query (rows are contiguous: candidates were generated query-major)
        lmax = max(int(per_q.max()), k)
        rank = torch.arange(total, device=device) - (torch.cumsum(per_q, 0) - per_q)[row]
        mat = torch.full((q_take, lmax), float("inf"), dtype=pts.dtype, device=device)
        mat[row, rank] = d
        out.append(torch.topk(mat, k, dim=1, largest=False).values)
        s += q_take
    return torch.cat(out)
