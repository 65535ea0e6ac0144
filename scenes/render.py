"""A ray-casting renderer for tiny textured scenes (trimesh + embree), independent of splat_cpu.

Convention: OpenCV camera axes (x right, y down, z forward), ``c2w`` camera-to-world [4, 4],
K in pixels with the top-left pixel centre at (0.5, 0.5). One ray per pixel through its centre;
textures are pre-filtered when the scene is built (resized to about the on-screen resolution),
so that one ray per pixel does not alias. Intensities are linear.

A scene is a list of primitives: textured quads (a box is six) and textured spheres. Quads map
their texture with u along edge ``eu`` (image columns) and v along ``ev`` (image rows); spheres
use longitude/latitude in the sphere's own frame.

Materials: a primitive is matte (``specular = 0``, the default: its radiance is its texture,
the same from every direction) or glossy: a Blinn-Phong highlight of a white directional light
(``RayScene.light``, the direction towards the light) brightens the texture towards white,
``texture + (1 - texture) * specular * max(0, n.h) ** shininess`` with h the half vector of the
light and view directions and n the surface normal facing the viewer (zero where the light is
behind the surface). It depends on the view direction and stays in [0, 1] for textures in [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, overload

import numpy as np
import trimesh

__all__ = ["Quad", "Sphere", "RayScene", "render", "pixel_rays", "project_points", "glossy", "DEFAULT_LIGHT"]

DEFAULT_LIGHT = (0.25, -0.55, -0.8)  # direction towards the light of glossy surfaces (world; up is -y)


@dataclass
class Quad:
    """A flat textured parallelogram: corners o, o + eu, o + eu + ev, o + ev (world units)."""

    origin: np.ndarray  # [3]
    eu: np.ndarray  # [3] along texture columns
    ev: np.ndarray  # [3] along texture rows
    texture: np.ndarray  # [th, tw, D] linear intensity
    specular: float = 0.0  # weight of the view-dependent highlight in [0, 1] (0: matte)
    shininess: float = 50.0  # Blinn-Phong exponent of the highlight (larger: smaller, sharper)

    def normal(self, pts: np.ndarray) -> np.ndarray:  # [R, 3] -> [R, 3] unit (one side; render faces it to the ray)
        n = np.cross(np.asarray(self.eu, np.float64), np.asarray(self.ev, np.float64))
        return np.broadcast_to(n / np.linalg.norm(n), np.shape(pts)).copy()

    def mesh(self) -> trimesh.Trimesh:
        o, u, v = (np.asarray(a, np.float64) for a in (self.origin, self.eu, self.ev))
        verts = np.stack([o, o + u, o + u + v, o + v])
        return trimesh.Trimesh(verts, np.array([[0, 1, 2], [0, 2, 3]]), process=False)

    def uv(self, pts: np.ndarray) -> np.ndarray:  # [R, 3] -> [R, 2] in [0, 1]
        d = pts - np.asarray(self.origin)
        u = d @ np.asarray(self.eu) / float(np.dot(self.eu, self.eu))
        v = d @ np.asarray(self.ev) / float(np.dot(self.ev, self.ev))
        return np.stack([u, v], -1)

    @property
    def corners(self) -> np.ndarray:  # [4, 3]
        o, u, v = (np.asarray(a, np.float64) for a in (self.origin, self.eu, self.ev))
        return np.stack([o, o + u, o + u + v, o + v])


@dataclass
class Sphere:
    """A textured sphere (tessellated as an icosphere for ray casting)."""

    center: np.ndarray  # [3]
    radius: float
    texture: np.ndarray  # [th, tw, D]
    subdivisions: int = 4
    specular: float = 0.0  # weight of the view-dependent highlight in [0, 1] (0: matte)
    shininess: float = 50.0  # Blinn-Phong exponent of the highlight

    def normal(self, pts: np.ndarray) -> np.ndarray:  # [R, 3] -> [R, 3] unit, outward (analytic, not the mesh's)
        d = np.asarray(pts, np.float64) - np.asarray(self.center, np.float64)
        return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)

    def mesh(self) -> trimesh.Trimesh:
        m = trimesh.creation.icosphere(subdivisions=self.subdivisions, radius=self.radius)
        m.apply_translation(np.asarray(self.center, np.float64))
        return m

    def uv(self, pts: np.ndarray) -> np.ndarray:
        d = (pts - np.asarray(self.center)) / self.radius
        u = np.arctan2(d[:, 0], d[:, 2]) / (2 * np.pi) + 0.5
        v = np.arccos(np.clip(d[:, 1], -1, 1)) / np.pi
        return np.stack([u, v], -1)


@dataclass
class RayScene:
    """Primitives merged into one trimesh for a single embree intersector."""

    primitives: list
    background: float = 0.0  # intensity of rays that hit nothing
    light: tuple[float, float, float] = DEFAULT_LIGHT  # direction towards the light of glossy primitives (world)
    mesh: trimesh.Trimesh = field(init=False, repr=False)
    tri_prim: np.ndarray = field(init=False, repr=False)  # [T] primitive index of each triangle

    def __post_init__(self) -> None:
        if not self.primitives:
            raise ValueError("primitives: a scene needs at least one primitive")
        d = {p.texture.shape[2] for p in self.primitives}
        if len(d) != 1:
            raise ValueError(f"primitives: textures must share a channel count, got {sorted(d)}")
        for i, p in enumerate(self.primitives):
            if not (0.0 <= p.specular <= 1.0):
                raise ValueError(f"primitives[{i}].specular: must be in [0, 1], got {p.specular!r}")
            if not (math.isfinite(p.shininess) and p.shininess > 0):
                raise ValueError(f"primitives[{i}].shininess: must be a positive finite number, got {p.shininess!r}")
        lt = np.asarray(self.light, np.float64)
        if lt.shape != (3,) or not np.isfinite(lt).all() or np.linalg.norm(lt) == 0:
            raise ValueError(f"light: must be a non-zero finite direction (x, y, z), got {self.light!r}")
        meshes = [p.mesh() for p in self.primitives]
        self.tri_prim = np.concatenate([np.full(len(m.faces), i) for i, m in enumerate(meshes)])
        mesh = trimesh.util.concatenate(meshes)
        assert isinstance(mesh, trimesh.Trimesh)  # typed as any Geometry; meshes concatenate to a Trimesh
        self.mesh = mesh

    @property
    def channels(self) -> int:
        return int(self.primitives[0].texture.shape[2])


def _bilinear(tex: np.ndarray, uv: np.ndarray, wrap_u: bool) -> np.ndarray:
    """[th, tw, D] texture sampled at uv [R, 2] in [0, 1] (texel centres at (i + 0.5) / n)."""
    th, tw, _ = tex.shape
    x = uv[:, 0] * tw - 0.5
    y = np.clip(uv[:, 1], 0, 1) * th - 0.5
    x0 = np.floor(x).astype(np.int64)
    y0 = np.floor(y).astype(np.int64)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    if wrap_u:
        xa, xb = x0 % tw, (x0 + 1) % tw
    else:
        xa, xb = np.clip(x0, 0, tw - 1), np.clip(x0 + 1, 0, tw - 1)
    ya, yb = np.clip(y0, 0, th - 1), np.clip(y0 + 1, 0, th - 1)
    top = tex[ya, xa] * (1 - fx) + tex[ya, xb] * fx
    bot = tex[yb, xa] * (1 - fx) + tex[yb, xb] * fx
    return top * (1 - fy) + bot * fy


def glossy(
    albedo: np.ndarray,  # [R, D] texture values in [0, 1]
    normal: np.ndarray,  # [R, 3] unit surface normals (either side)
    view: np.ndarray,  # [R, 3] unit ray directions, camera -> surface
    light: np.ndarray | tuple[float, float, float],  # [3] direction towards the light
    specular: float,
    shininess: float,
) -> np.ndarray:  # [R, D] in [0, 1] for albedo in [0, 1]
    """Blinn-Phong radiance of a glossy surface: ``albedo + (1 - albedo) * specular * max(0, n.h) ** shininess``
    (the texture where there is no highlight, towards white at its peak), n facing the viewer,
    h = normalize(l + v) (v towards the camera); no highlight where n.l <= 0."""
    v = -np.asarray(view, np.float64)
    n = np.asarray(normal, np.float64)
    n = np.where((np.einsum("ij,ij->i", n, v) < 0)[:, None], -n, n)
    lt = np.asarray(light, np.float64) / np.linalg.norm(light)
    h = v + lt
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    spec = np.maximum(np.einsum("ij,ij->i", n, h), 0.0) ** shininess * (n @ lt > 0)
    a = np.asarray(albedo, np.float64)
    return a + (1.0 - a) * (specular * spec[:, None])


def pixel_rays(
    c2w: np.ndarray,  # [4, 4]
    K: np.ndarray,  # [3, 3]
    width: int,
    height: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Ray origins and unit directions [H*W, 3] through every pixel centre (row-major)."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1).reshape(-1, 3)
    d = d_cam @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = np.broadcast_to(c2w[:3, 3], d.shape)
    return np.ascontiguousarray(o), d


def project_points(
    pts: np.ndarray,  # [P, 3] world
    c2w: np.ndarray,
    K: np.ndarray,
) -> np.ndarray:
    """Pixel coordinates [P, 2] (top-left pixel centre at (0.5, 0.5)) and nothing else."""
    w2c = np.linalg.inv(c2w)
    pc = pts @ w2c[:3, :3].T + w2c[:3, 3]
    return np.stack([K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2], K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2]], -1)


@overload
def render(
    scene: RayScene,
    c2w: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    return_depth: Literal[False] = False,
    batch_rays: int = 120_000,
) -> np.ndarray: ...


@overload
def render(
    scene: RayScene,
    c2w: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    return_depth: Literal[True],
    batch_rays: int = 120_000,
) -> tuple[np.ndarray, np.ndarray]: ...


def render(
    scene: RayScene,
    c2w: np.ndarray,  # [C, 4, 4] or [4, 4]
    K: np.ndarray,
    width: int,
    height: int,
    return_depth: bool = False,  # K [3, 3]
    batch_rays: int = 120_000,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Ray-cast ``scene`` from each camera: images [C, H, W, D] float32 linear (and, with
    ``return_depth``, z-depth [C, H, W] float32, 0 where nothing is hit). A [4, 4] c2w gives
    [H, W, D] (and [H, W])."""
    single = np.asarray(c2w).ndim == 2
    c2ws = np.asarray(c2w, np.float64).reshape(-1, 4, 4)
    if not np.isfinite(c2ws).all():
        raise ValueError("c2w: non-finite pose")
    npx = width * height
    d_ch = scene.channels
    img: np.ndarray = np.full((len(c2ws), npx, d_ch), scene.background, np.float32)
    depth: np.ndarray = np.zeros((len(c2ws), npx), np.float32)
    per = max(1, batch_rays // npx)
    for b0 in range(0, len(c2ws), per):
        cams = c2ws[b0 : b0 + per]
        rays = [pixel_rays(c, K, width, height) for c in cams]
        o = np.concatenate([r[0] for r in rays])
        d = np.concatenate([r[1] for r in rays])
        loc, iray, itri = scene.mesh.ray.intersects_location(o, d, multiple_hits=False)
        if len(iray) == 0:
            continue
        prim = scene.tri_prim[itri]
        vals = np.empty((len(iray), d_ch), np.float32)
        for pi, p in enumerate(scene.primitives):
            sel = np.flatnonzero(prim == pi)
            if len(sel):
                albedo = _bilinear(p.texture, p.uv(loc[sel]), isinstance(p, Sphere))
                if p.specular > 0:  # matte primitives stay exactly their texture
                    albedo = glossy(albedo, p.normal(loc[sel]), d[iray[sel]], scene.light, p.specular, p.shininess)
                vals[sel] = albedo
        cam = iray // npx
        pix = iray % npx
        img[b0 + cam, pix] = vals
        if return_depth:
            fwd = cams[cam][:, :3, 2]
            depth[b0 + cam, pix] = np.einsum("ij,ij->i", loc - o[iray], fwd)
    img = img.reshape(len(c2ws), height, width, d_ch)
    depth = depth.reshape(len(c2ws), height, width)
    if single:
        img, depth = img[0], depth[0]
    return (img, depth) if return_depth else img
