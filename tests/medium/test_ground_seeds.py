"""Ground seeds (``--pipeline.ground-seeds``): points on the ground plane where training rays below
the horizon see no seed point, beyond the view's farthest ones."""

from __future__ import annotations

import math

import torch

from components.data.cameras import Cameras
from pipelines.tridehaze.ground_seeds import FAR_QUANTILE, MAX_REACH, ground_seeds

W, H = 48, 36
UP = torch.tensor([0.0, 0.0, 1.0])


def _look_at(eye: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Camera-to-world [4, 4], OpenCV axes (x right, y down, z forward), world z up."""
    fwd = (target - eye) / (target - eye).norm()
    right = torch.linalg.cross(fwd, UP)
    right = right / right.norm()
    down = torch.linalg.cross(fwd, right)
    c2w = torch.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, fwd, eye
    return c2w


class _Views:
    """The part of a data manager ground_seeds reads: cameras on a ring 1 unit above the ground,
    looking past the centre, and flat grey images."""

    def __init__(self, pitch: float = -0.15, n: int = 6) -> None:
        self.train_indices = list(range(n))
        c2ws = []
        for k in range(n):
            a = 2 * math.pi * k / n
            eye = torch.tensor([1.5 * math.cos(a), 1.5 * math.sin(a), 1.0])
            target = torch.tensor([-3.0 * math.cos(a), -3.0 * math.sin(a), 1.0 + 4.5 * math.tan(pitch)])
            c2ws.append(_look_at(eye, target))
        one = lambda x: torch.full((n,), float(x))  # noqa: E731
        self.cams = Cameras(torch.stack(c2ws), one(40.0), one(40.0), one(W / 2), one(H / 2), one(W), one(H))

    def camera(self, i: int) -> Cameras:
        return self.cams[i]

    def image(self, i: int) -> torch.Tensor:
        return torch.full((H, W, 3), 0.1 * (i + 1))


def _disc(n: int = 400) -> torch.Tensor:
    """Seed points on the ground (z = 0) within radius 1.2 of the centre, and a few on a pole."""
    g = torch.Generator().manual_seed(0)
    r, a = 1.2 * torch.rand(n, generator=g).sqrt(), 2 * math.pi * torch.rand(n, generator=g)
    ground = torch.stack([r * a.cos(), r * a.sin(), torch.zeros(n)], dim=-1)
    pole = torch.stack([torch.zeros(20), torch.zeros(20), torch.linspace(0.1, 1.5, 20)], dim=-1)
    return torch.cat([ground, pole])


def test_the_seeds_lie_on_the_ground_beyond_the_cloud():
    views, cloud = _Views(), _disc()
    pts, cols = ground_seeds(views, cloud, UP, count=600)
    assert 0 < len(pts) <= 600 and cols.shape == (len(pts), 3)
    assert torch.allclose(pts[:, 2], torch.zeros(len(pts)), atol=1e-4)  # the ground is the cloud's lowest 2 %
    radius = pts[:, :2].norm(dim=-1)
    assert float(radius.min()) > 1.2  # beyond the disc of seed points
    centres = views.cams.centers
    reach = (pts[:, None] - centres[None]).norm(dim=-1).min(dim=1).values
    far = float(torch.quantile((cloud[:, None] - centres[None]).norm(dim=-1).max(dim=1).values, FAR_QUANTILE))
    assert float(reach.max()) < MAX_REACH * far * 1.01
    assert {round(float(c), 3) for c in cols[:, 0]} <= {
        round(0.1 * (i + 1), 3) for i in range(6)
    }  # the views' colours


def test_fewer_seeds_than_views_stay_within_the_count():
    pts, cols = ground_seeds(_Views(), _disc(), UP, count=4)  # 6 views
    assert len(pts) == 4 and len(cols) == 4


def test_the_same_seed_gives_the_same_points():
    views, cloud = _Views(), _disc()
    a, _ = ground_seeds(views, cloud, UP, count=300, seed=3)
    b, _ = ground_seeds(views, cloud, UP, count=300, seed=3)
    assert torch.equal(a, b)


def test_cameras_looking_up_or_a_missing_cloud_give_none():
    up_views = _Views(pitch=0.7)  # the whole image above the horizon
    pts, cols = ground_seeds(up_views, _disc(), UP, count=300)
    assert pts.shape == (0, 3) and cols.shape == (0, 3)
    few = _disc()[:5]  # no view sees ten points: nothing to judge the cloud's reach by
    assert len(ground_seeds(_Views(), few, UP, count=300)[0]) == 0
