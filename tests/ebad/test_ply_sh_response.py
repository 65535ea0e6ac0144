"""The PLY's SH coefficients through a non-linear camera response (``ebad.export.to_recorded_params``): fitted
over directions, since a curve cannot go through the coefficients one by one."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from ebad.export import fibonacci_directions, from_recorded_params, recorded_colors, to_recorded_params
from ebad.response import Response
from splat_cpu._sh import sh_basis


def _response(gamma: float, black: float = 0.04, gain: float = 1.25) -> Response:
    r = Response("gamma")
    with torch.no_grad():
        r.raw.copy_(torch.tensor([math.log(black / (0.5 - black)), math.log(gain), math.log(gamma)]))
    return r


def _params(n: int = 300, degree: int = 3, D: int = 3, rest_scale: float = 0.08) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    dc = (torch.rand(n, D, generator=g) * 0.5 + 0.25 - 0.5) / 0.28209479177387814  # colours 0.25 .. 0.75
    rest = torch.randn(n, (degree + 1) ** 2 - 1, D, generator=g) * rest_scale
    return {"means": torch.randn(n, 3, generator=g), "colors": dc, "sh_rest": rest}


def _colour(p: dict[str, torch.Tensor], dirs: torch.Tensor) -> np.ndarray:  # -> [S, N, D], INRIA's eval_sh + 0.5
    degree = math.isqrt(p["sh_rest"].shape[1] + 1) - 1
    coeffs = torch.cat([p["colors"][:, None], p["sh_rest"]], 1).double()
    return np.clip(torch.einsum("sk,nkd->snd", sh_basis(degree, dirs.double()), coeffs).numpy() + 0.5, 0, None)


def _random_dirs(n: int = 500) -> torch.Tensor:
    d = torch.randn(n, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    return d / d.norm(dim=1, keepdim=True)


def test_fibonacci_directions_are_unit_and_spread():
    d = fibonacci_directions(128)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(d.mean(0), 0.0, atol=0.02)


def test_an_affine_response_fits_exactly():
    # gamma 1 with a black level and a gain: affine, so the fitted SH are exact (constants go into the DC)
    p = _params()
    p["colors"] = p["colors"] * 0.3  # colours near 0.5: gain * colour stays below 1 and above 0 in every direction
    r = _response(1.0)
    dirs = _random_dirs()
    want = recorded_colors(_colour(p, dirs).reshape(-1, 3), r, saturate=False).reshape(len(dirs), -1, 3)
    np.testing.assert_allclose(_colour(to_recorded_params(p, r), dirs), want, atol=1e-5)  # float32 coefficients
    # and the identity leaves the parameters untouched
    assert to_recorded_params(p, Response("linear")) is p


def test_degree_zero_and_a_view_independent_model_are_exact():
    r = _response(0.75)
    p = _params(rest_scale=0.0)  # degree 3 coefficients, all zero: view-independent colour
    q = to_recorded_params(p, r)
    dc_only = to_recorded_params({"colors": p["colors"], "means": p["means"]}, r)
    torch.testing.assert_close(q["colors"], dc_only["colors"], atol=1e-6, rtol=1e-6)
    assert float(q["sh_rest"].abs().max()) < 1e-6


# measured: max 0.0024, mean 9.5e-5, round trip 4.6e-5 (rest 0.02); max 0.0116, mean 3.9e-4, round trip 5.8e-4 (0.04)
@pytest.mark.parametrize(
    "rest_scale,max_err,mean_err,back_err", [(0.02, 0.003, 1.2e-4, 1e-4), (0.04, 0.013, 4.5e-4, 1e-3)]
)
def test_a_gamma_075_ply_evaluated_inria_style_matches_the_response_of_the_model_colour(
    rest_scale, max_err, mean_err, back_err
):
    # colours 0.25 .. 0.75 at the DC, view-dependent parts of +-0.1 / +-0.2 (never clamped at 0: min 0.17 / 0.08)
    p = _params(rest_scale=rest_scale)
    r = _response(0.75)
    dirs = _random_dirs()
    want = recorded_colors(_colour(p, dirs).reshape(-1, 3), r, saturate=False).reshape(len(dirs), -1, 3)
    got = _colour(to_recorded_params(p, r), dirs)
    err = np.abs(got - want)
    assert err.max() < max_err and err.mean() < mean_err
    # pushing each coefficient through the curve on its own (the DC only) is far worse in some direction
    dc_only = to_recorded_params({"colors": p["colors"], "means": p["means"]}, r)
    naive = _colour({**p, "colors": dc_only["colors"]}, dirs)
    assert np.abs(naive - want).max() > 3 * err.max()
    # and the run folder's read-back (from_recorded_params) returns the model's colours
    back = _colour(from_recorded_params(to_recorded_params(p, r), r), dirs)
    assert np.abs(back - _colour(p, dirs)).max() < back_err
