"""Which Gaussians lie in free space in front of the views' surfaces (components/gaussians/free_space.py)."""

from __future__ import annotations

import math

import torch

from components.gaussians.free_space import floaters, in_front_counts


def _view(depth: torch.Tensor, yaw: float = 0.0):
    """A camera at the origin looking down +z (turned by ``yaw`` about y), 10 x 8 pixels, focal 10."""
    c, s = math.cos(yaw), math.sin(yaw)
    viewmat = torch.eye(4)
    viewmat[:3, :3] = torch.tensor([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])
    K = torch.tensor([[10.0, 0.0, 5.0], [0.0, 10.0, 4.0], [0.0, 0.0, 1.0]])
    return viewmat, K, depth


def test_counts_in_front_on_and_behind_the_surface():
    wall = torch.full((8, 10), 2.0)  # a wall at z = 2
    wall[0, :] = float("nan")  # top row: sky, no surface
    means = torch.tensor(
        [
            [0.0, 0.0, 1.0],  # half-way to the wall: in free space
            [0.0, 0.0, 1.8],  # 10 % in front: within a 15 % margin
            [0.0, 0.0, 2.0],  # on the wall
            [0.0, 0.0, 3.0],  # behind it
            [0.0, -0.39, 1.0],  # projects onto the sky row: not counted
            [5.0, 0.0, 1.0],  # outside the image
            [0.0, 0.0, -1.0],  # behind the camera
        ]
    )
    in_front, seen = in_front_counts(means, [_view(wall)], margin=0.15)
    assert seen.tolist() == [1, 1, 1, 1, 0, 0, 0]
    assert in_front.tolist() == [1, 0, 0, 0, 0, 0, 0]


def test_floaters_need_most_of_their_views():
    wall = torch.full((8, 10), 2.0)
    near_wall = torch.full((8, 10), 1.05)  # another view's surface lies right at the Gaussian
    means = torch.tensor([[0.0, 0.0, 1.0]])
    views = [_view(wall), _view(wall), _view(near_wall)]
    in_front, seen = in_front_counts(means, views, margin=0.15)
    assert (in_front.item(), seen.item()) == (2, 3)
    assert floaters(in_front, seen, share=0.5).tolist() == [True]
    assert floaters(in_front, seen, share=0.7).tolist() == [False]
    one = in_front_counts(means, views[:1], margin=0.15)
    assert floaters(*one, share=0.5).tolist() == [False]  # a single view is not enough by default
    assert floaters(*one, share=0.5, min_views=1).tolist() == [True]


def test_a_turned_camera_projects_through_its_rotation():
    wall = torch.full((8, 10), 2.0)
    point = torch.tensor([[math.sin(0.3) * 1.0, 0.0, math.cos(0.3) * 1.0]])  # on the turned axis, 1 away
    in_front, seen = in_front_counts(point, [_view(wall, yaw=0.3)], margin=0.15)
    assert (in_front.item(), seen.item()) == (1, 1)
