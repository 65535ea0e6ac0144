"""The ray-cast renderer against analytic projections and ray-plane / ray-sphere intersections."""

import numpy as np
import pytest
from matplotlib.path import Path as MplPath

from scenes.render import Quad, RayScene, Sphere, pixel_rays, project_points, render
from scenes.synth import look_at

W, H = 64, 48
K = np.array([[52.0, 0.0, 31.0], [0.0, 50.0, 25.5], [0.0, 0.0, 1.0]])


def _camera():
    return look_at(np.array([0.7, -0.4, -0.5]), np.array([0.1, 0.15, 4.0]))


def _tilted_quad(texture):
    return Quad(np.array([-1.2, -0.8, 3.5]), np.array([2.1, 0.2, 0.9]), np.array([-0.3, 1.7, 0.4]), texture)


def test_quad_coverage_matches_analytic_projection_of_its_corners():
    q = _tilted_quad(np.ones((8, 8, 1), np.float32))
    c2w = _camera()
    img = render(RayScene([q], background=0.0), c2w, K, W, H)[..., 0]
    corners = project_points(q.corners, c2w, K)  # pixel coords, top-left pixel centre (0.5, 0.5)
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    centres = np.stack([u.ravel(), v.ravel()], 1)
    poly = MplPath(corners)
    inside = poly.contains_points(centres).reshape(H, W)
    # distance of each pixel centre to the polygon's edges: skip the ones within 1e-3 px of an edge
    d = np.full(len(centres), np.inf)
    for a, b in zip(corners, np.roll(corners, -1, 0)):
        ab = b - a
        s = np.clip(((centres - a) @ ab) / (ab @ ab), 0, 1)
        d = np.minimum(d, np.linalg.norm(centres - (a + s[:, None] * ab), axis=1))
    clear = d.reshape(H, W) > 1e-3
    assert inside.sum() > 300 and (~inside).sum() > 300  # the quad covers part of the image
    np.testing.assert_array_equal(img[clear] > 0.5, inside[clear])


def test_quad_texture_and_depth_match_analytic_ray_plane_intersection():
    rng = np.random.default_rng(0)
    tex = rng.uniform(0, 1, (16, 24, 1)).astype(np.float32)
    q = _tilted_quad(tex)
    c2w = _camera()
    img, depth = render(RayScene([q], background=-1.0), c2w, K, W, H, return_depth=True)
    o, d = pixel_rays(c2w, K, W, H)
    n = np.cross(q.eu, q.ev)
    s = ((q.origin - o) @ n) / (d @ n)
    p = o + s[:, None] * d
    uv = q.uv(p)
    hit = (uv >= 0).all(1) & (uv <= 1).all(1)
    inner = (uv > 0.02).all(1) & (uv < 0.98).all(1)
    z_true = (p - o) @ c2w[:3, 2]
    np.testing.assert_allclose(depth.ravel()[inner], z_true[inner], rtol=1e-5)
    assert (depth.ravel()[~hit & ((uv < -0.02) | (uv > 1.02)).any(1)] == 0).all()
    # texture: bilinear lookup at the analytic uv
    th, tw = tex.shape[:2]
    x, y = uv[inner, 0] * tw - 0.5, uv[inner, 1] * th - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    cl = lambda a, m: np.clip(a, 0, m - 1)  # noqa: E731
    t = tex[..., 0]
    want = (1 - fy) * ((1 - fx) * t[cl(y0, th), cl(x0, tw)] + fx * t[cl(y0, th), cl(x0 + 1, tw)]) + fy * (
        (1 - fx) * t[cl(y0 + 1, th), cl(x0, tw)] + fx * t[cl(y0 + 1, th), cl(x0 + 1, tw)]
    )
    np.testing.assert_allclose(img[..., 0].ravel()[inner], want, atol=1e-4)


def test_sphere_depth_matches_analytic_ray_sphere_intersection():
    sph = Sphere(np.array([0.2, 0.1, 4.0]), 1.0, np.full((4, 8, 1), 0.7, np.float32), subdivisions=5)
    c2w = _camera()
    img, depth = render(RayScene([sph]), c2w, K, W, H, return_depth=True)
    o, d = pixel_rays(c2w, K, W, H)
    oc = o - sph.center
    b = (d * oc).sum(1)
    disc = b * b - ((oc * oc).sum(1) - 1.0)
    hit = disc > 0.05  # away from the silhouette, where the tessellation decides
    s = -b[hit] - np.sqrt(disc[hit])
    z = s * (d[hit] @ c2w[:3, 2])
    np.testing.assert_allclose(depth.ravel()[hit], z, rtol=2e-3)  # icosphere level 5: chord error < 1e-3 r
    assert (depth.ravel()[disc < -0.05] == 0).all()
    np.testing.assert_allclose(img[..., 0].ravel()[hit], 0.7, atol=1e-6)


def test_batched_render_equals_single_renders_and_shapes():
    q = _tilted_quad(np.random.default_rng(1).uniform(0, 1, (8, 8, 3)).astype(np.float32))
    scene = RayScene([q])
    poses = np.stack([_camera(), look_at(np.array([-0.5, 0.0, 0.0]), np.array([0.0, 0.0, 4.0]))])
    batch = render(scene, poses, K, W, H, batch_rays=W * H)  # forces one camera per intersector call
    assert batch.shape == (2, H, W, 3) and batch.dtype == np.float32
    for i in range(2):
        np.testing.assert_array_equal(batch[i], render(scene, poses[i], K, W, H))


def test_bad_scene_inputs():
    with pytest.raises(ValueError, match="primitives"):
        RayScene([])
    q1 = _tilted_quad(np.ones((4, 4, 1), np.float32))
    q3 = _tilted_quad(np.ones((4, 4, 3), np.float32))
    with pytest.raises(ValueError, match="channel"):
        RayScene([q1, q3])
    with pytest.raises(ValueError, match="c2w"):
        render(RayScene([q1]), np.full((4, 4), np.nan), K, W, H)
