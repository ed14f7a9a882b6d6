"""Where the seed points land in a view (the seen-light gate's located check): the pixels within one
pixel of a point the view sees, occluded points left out."""

from __future__ import annotations

import torch

from components.data.cameras import Cameras
from pipelines.tridehaze.priors import located_pixels

W, H = 64, 48


def _camera() -> Cameras:
    """3 units behind the origin, looking along +z (OpenCV axes), focal 100 px."""
    c2w = torch.eye(4)
    c2w[2, 3] = -3.0
    one = lambda x: torch.tensor([x])  # noqa: E731
    return Cameras(c2w[None], one(100.0), one(100.0), one(32.5), one(24.5), one(W), one(H))


def test_a_seen_point_marks_its_pixel_and_the_eight_around_it():
    mask = located_pixels(_camera(), torch.tensor([[0.0, 0.0, 0.0]]))  # pixel (u 32, v 24)
    assert mask.shape == (H, W) and mask.dtype == torch.bool
    assert int(mask.sum()) == 9 and mask[23:26, 31:34].all()


def test_points_behind_the_camera_outside_the_image_or_occluded_mark_nothing():
    behind = torch.tensor([[0.0, 0.0, -5.0]])
    outside = torch.tensor([[10.0, 0.0, 0.0]])  # u = 32.5 + 100 * 10 / 3, off the image
    assert not located_pixels(_camera(), torch.cat([behind, outside])).any()
    # a near point and one far behind it 2 px to its right, seen only through a gap in the points
    near_far = torch.tensor([[0.0, 0.0, -1.0], [0.26, 0.0, 10.0]])  # u 32.5 and 32.5 + 100 * 0.26 / 13
    mask = located_pixels(_camera(), near_far)
    assert int(mask.sum()) == 9 and mask[24, 32]  # the far point is dropped by the occlusion filter
    assert located_pixels(_camera(), torch.zeros(0, 3)).sum() == 0
