"""``--pipeline.sky-shell N``: Gaussians seeded on the sphere around the medium's box, kept where a
training view sees them and coloured by what the views show there."""

from __future__ import annotations

import math

import torch

from components.data.cameras import Cameras
from components.medium.base import FieldBounds
from pipelines.tridehaze.sky_shell import fibonacci_sphere, sky_shell

H, W, F = 24, 32, 20.0


class _Views:
    """One camera at the box centre looking down +z (OpenCV axes): the top half of its image is one
    colour and the bottom half another; a second, unused camera is not a training view."""

    def __init__(self) -> None:
        c2w = torch.eye(4).repeat(2, 1, 1)  # [2, 4, 4]
        c2w[1, :3, :3] = torch.diag(torch.tensor([1.0, -1.0, -1.0]))  # looks down -z
        one = torch.ones(2)
        self.cams = Cameras(
            c2w, F * one, F * one, W / 2 * one, H / 2 * one, (W * one).long(), (H * one).long()
        )
        img = torch.zeros(H, W, 3)
        img[: H // 2] = torch.tensor([0.2, 0.4, 0.9])
        img[H // 2 :] = torch.tensor([0.6, 0.5, 0.1])
        self.images = [img, torch.ones(H, W, 3)]
        self.train_indices = [0]

    def camera(self, i: int) -> Cameras:
        return self.cams[i]

    def image(self, i: int) -> torch.Tensor:
        return self.images[i]


def test_fibonacci_sphere_is_even_and_on_the_unit_sphere() -> None:
    pts = fibonacci_sphere(2000)  # [2000, 3]
    torch.testing.assert_close(pts.norm(dim=-1), torch.ones(2000))
    assert pts.mean(0).abs().max() < 0.01  # no side favoured
    octant = ((pts > 0).long() * torch.tensor([1, 2, 4])).sum(-1)  # [2000] which octant
    counts = torch.bincount(octant, minlength=8).float()
    assert counts.min() > 0.9 * 250 and counts.max() < 1.1 * 250


def test_shell_keeps_what_the_training_views_see_with_their_colours() -> None:
    bounds = FieldBounds(torch.zeros(3), torch.tensor([1.0, 2.0, 2.0]))
    pts, colors = sky_shell(_Views(), bounds, 4000)  # type: ignore[arg-type]
    torch.testing.assert_close(pts.norm(dim=-1), torch.full((len(pts),), 3.0))  # circumscribing radius
    # the view spans atan(16 / 20) by atan(12 / 20) either side of +z: a solid angle of
    # 4 asin(sin a sin b) of the sphere's 4 pi, about 10.4 %
    a, b = math.atan(16 / 20), math.atan(12 / 20)
    expected = 4000 * 4 * math.asin(math.sin(a) * math.sin(b)) / (4 * math.pi)
    assert abs(len(pts) - expected) < 0.05 * expected
    assert (pts[:, 2] > 0).all()  # nothing behind the camera, nothing from the unused view
    up = pts[:, 1] < 0  # OpenCV: image top is -y
    torch.testing.assert_close(colors[up], torch.tensor([0.2, 0.4, 0.9]).expand(int(up.sum()), 3))
    torch.testing.assert_close(colors[~up], torch.tensor([0.6, 0.5, 0.1]).expand(int((~up).sum()), 3))
