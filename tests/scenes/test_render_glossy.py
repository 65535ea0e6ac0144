"""The glossy (view-dependent) material of the ray-caster and the "glossy" scene (issue 29 s.3); the matte
scenes' images unchanged bit for bit."""

import hashlib
from dataclasses import replace

import numpy as np
import pytest

from scenes.render import DEFAULT_LIGHT, Quad, RayScene, Sphere, glossy, render
from scenes.synth import SCENES, TARGET, _intrinsics, look_at


def _hash(a: np.ndarray) -> str:
    m = hashlib.sha256()
    a = np.ascontiguousarray(a)
    m.update(str(a.dtype).encode())
    m.update(str(a.shape).encode())
    m.update(a.tobytes())
    return m.hexdigest()[:16]


W, H = 9, 7
K_ODD = np.array([[8.0, 0.0, 4.5], [0.0, 8.0, 3.5], [0.0, 0.0, 1.0]])  # pixel (4, 3)'s ray is the optical axis
P = np.array([0.0, 0.0, 5.0])  # a point of the quad below, seen at pixel (4, 3) by a camera looking at it


def _wall(specular: float, shininess: float = 20.0) -> RayScene:
    tex = np.full((4, 4, 1), 0.5, np.float32)
    return RayScene(
        [Quad(np.array([-4.0, -4.0, 5.0]), np.array([8.0, 0, 0]), np.array([0, 8.0, 0]), tex, specular, shininess)]
    )


def _seen_from(scene: RayScene, eye) -> float:
    return float(render(scene, look_at(np.asarray(eye, np.float64), P), K_ODD, W, H)[3, 4, 0])


def test_a_glossy_point_seen_from_two_directions_has_two_radiances():
    eyes = ([-1.5625, 3.4375, 0.0], [3.0, -1.0, 1.0])  # the first sees P along the light's mirror direction
    matte = [_seen_from(_wall(0.0), e) for e in eyes]
    assert matte == [0.5, 0.5]  # a matte surface looks the same from everywhere
    shiny = [_seen_from(_wall(0.8), e) for e in eyes]
    assert abs(shiny[0] - shiny[1]) > 0.1
    # Blinn-Phong by hand: the normal facing the viewer (-z), h = normalize(l + v)
    lt = np.asarray(DEFAULT_LIGHT) / np.linalg.norm(DEFAULT_LIGHT)
    for e, got in zip(eyes, shiny, strict=True):
        v = (np.asarray(e) - P) / np.linalg.norm(np.asarray(e) - P)
        h = (lt + v) / np.linalg.norm(lt + v)
        want = 0.5 + 0.5 * 0.8 * max(0.0, -h[2]) ** 20.0
        assert got == pytest.approx(want, abs=1e-6)
    # pinned: the peak 0.5 + 0.5 * 0.8 at the mirror direction, a faint sheen far from it
    assert shiny == pytest.approx([0.9, 0.50686], abs=1e-4)


def test_no_highlight_where_the_light_is_behind_the_surface_and_sphere_normals_are_analytic():
    back = RayScene(_wall(1.0).primitives, light=(0.0, 0.0, 1.0))  # the light behind the wall
    assert _seen_from(back, [0.0, 0.0, 0.0]) == 0.5
    tex = np.full((4, 8, 1), 0.3, np.float32)
    ball = RayScene([Sphere(np.array([0.0, 0.0, 6.0]), 1.0, tex, specular=1.0, shininess=50.0)], light=(0.0, 0.0, -1.0))
    img = render(ball, look_at(np.zeros(3), np.array([0.0, 0.0, 6.0])), K_ODD, W, H)
    assert img[3, 4, 0] == pytest.approx(1.0, abs=1e-3)  # the normal points at the camera and the light: the peak
    assert img.max() <= 1.0 and img[3, 0, 0] < 0.9


def test_glossy_is_bounded_in_0_1():
    rng = np.random.default_rng(0)
    n = 2000
    albedo = rng.random((n, 3))
    albedo[:10] = 1.0
    albedo[10:20] = 0.0
    normal = rng.standard_normal((n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    view = rng.standard_normal((n, 3))
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    for ks, s in ((1.0, 1.0), (0.5, 50.0), (1.0, 1e-3)):
        out = glossy(albedo, normal, view, np.array([0.3, -0.5, -0.8]), ks, s)
        assert out.min() >= 0.0 and out.max() <= 1.0 and (out >= albedo - 1e-12).all()


@pytest.mark.parametrize(
    "kw, word",
    [({"specular": 1.5}, "primitives[0].specular"), ({"shininess": 0.0}, "primitives[0].shininess")],
)
def test_bad_material_names_the_field(kw, word):
    tex = np.full((2, 2, 1), 0.5, np.float32)
    with pytest.raises(ValueError, match=word.replace("[", r"\[").replace("]", r"\]")):
        RayScene([Quad(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), tex, **kw)])
    with pytest.raises(ValueError, match="light"):
        RayScene([Quad(np.zeros(3), np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), tex)], light=(0.0, 0.0, 0.0))


def _orbit_pose(deg: float) -> np.ndarray:
    a = np.radians(deg)
    eye = TARGET + 4.0 * np.array([np.sin(a), 0.0, -np.cos(a)])
    eye[1] = -0.35
    return look_at(eye, TARGET)


@pytest.mark.parametrize("rgb", [False, True])
def test_glossy_scene_has_highlights_that_move_with_the_view(rgb):
    K = _intrinsics(64, 48)
    scene = SCENES["glossy"](64, rgb)
    matte = RayScene([replace(p, specular=0.0) for p in scene.primitives], scene.background, scene.light)
    assert scene.channels == (3 if rgb else 1)
    lifts = []
    for deg in (-14.0, 14.0):
        g = render(scene, _orbit_pose(deg), K, 64, 48)
        m = render(matte, _orbit_pose(deg), K, 64, 48)
        assert g.min() >= 0.0 and g.max() <= 1.0 and (g >= m).all()
        lifts.append((g - m).max(-1))
    assert (lifts[0] > 0.2).mean() > 0.01  # visible highlights
    assert np.abs(lifts[0] - lifts[1]).max() > 0.2  # that move as the camera moves


# sha256 (16 hex) of render(SCENES[name](64, rgb)) at one pose, computed on main (4dff722) before the glossy
# material existed: the matte scenes render bit for bit as before
MATTE_PINS = {
    ("boxes", False): "062b10b8dc20415e",
    ("boxes", True): "3b2632e4edbefe48",
    ("spheres", False): "afb74a2d3792be59",
    ("spheres", True): "40c65137fb194793",
}


@pytest.mark.parametrize("name, rgb", sorted(MATTE_PINS))
def test_matte_scenes_render_unchanged_bit_for_bit(name, rgb):
    K = _intrinsics(64, 48)
    c2w = look_at(np.array([0.3, -0.35, 0.0]), TARGET)
    assert _hash(render(SCENES[name](64, rgb), c2w, K, 64, 48)) == MATTE_PINS[(name, rgb)]
