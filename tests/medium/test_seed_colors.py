"""``--pipeline.seed-colors observed``: each observation of a seed point dehazed at its own distance
recovers the clean colour that a single colour dehazed at the nearest camera's distance does not."""

from __future__ import annotations

import torch

from components.data.cameras import Cameras
from components.losses.depth_priors import project_points
from pipelines.tridehaze.priors import MediumEstimate, dehaze_point_colors, observed_point_colors

H, W, F = 48, 64, 40.0


class _Views:
    """Two cameras looking down +z, at z = 0 and z = -4, and their hazy images of the points."""

    def __init__(self, points: torch.Tensor, clean: torch.Tensor, beta: float, light: torch.Tensor) -> None:
        c2w = torch.eye(4).repeat(2, 1, 1)  # [2, 4, 4] OpenCV axes
        c2w[1, 2, 3] = -4.0
        one = torch.ones(2)
        self.cams = Cameras(
            c2w, F * one, F * one, W / 2 * one, H / 2 * one, (W * one).long(), (H * one).long()
        )
        self.images = []
        for i in range(2):
            cam = self.cams[i]
            pc, uv = project_points(points, cam.viewmats()[0], cam.Ks()[0])
            T = torch.exp(-beta * pc.norm(dim=-1))[:, None]  # [M, 1]
            img = torch.zeros(H, W, 3)
            img[uv[:, 1].long(), uv[:, 0].long()] = clean * T + light * (1 - T)
            self.images.append(img)
        self.train_indices = [0, 1]

    def camera(self, i: int) -> Cameras:
        return self.cams[i]

    def image(self, i: int) -> torch.Tensor:
        return self.images[i]


def test_observed_colours_recover_the_clean_colour_where_the_nearest_camera_does_not():
    g = torch.Generator().manual_seed(0)
    xs = torch.linspace(-2.0, 2.0, 6)
    grid = torch.stack(torch.meshgrid(xs, xs, indexing="ij"), dim=-1).reshape(-1, 2)  # [36, 2]
    points = torch.cat([grid, torch.full((36, 1), 4.0)], dim=1)  # [36, 3] a wall at z = 4
    clean = torch.rand(36, 3, generator=g)
    beta, light = 0.15, torch.tensor([0.8, 0.8, 0.85])
    views = _Views(points, clean, beta, light)
    est = MediumEstimate(light, beta)
    observed, seen = observed_point_colors(views, [0, 1], points, est)
    assert bool(seen.all())
    torch.testing.assert_close(observed, clean.clamp(0, 1), atol=1e-4, rtol=0)
    # the dataset's one colour, seen from the far camera, dehazed at the near camera's distance
    far = views.images[1]
    pc, uv = project_points(points, views.cams[1].viewmats()[0], views.cams[1].Ks()[0])
    colour = far[uv[:, 1].long(), uv[:, 0].long()]
    nearest = dehaze_point_colors(points, colour, views.cams.camtoworlds[:, :3, 3], est)
    assert float((nearest - clean).abs().mean()) > 0.1  # left hazy: too bright
    assert float((nearest - clean).mean()) > 0.05
