"""Numerical constants of the rasteriser (gsplat "classic" mode).

Every path (the torch reference, the numba kernels and the brute-force compositor in the
tests) uses exactly these values.
"""

ALPHA_MAX = 0.999
"""alpha = min(ALPHA_MAX, o * exp(-sigma)): keeps 1 - alpha >= 1e-3 so T can be recovered by division."""

ALPHA_MIN = 1.0 / 255.0
"""A Gaussian whose alpha at a pixel is below this is skipped at that pixel."""

T_MIN = 1e-4
"""A pixel stops before the Gaussian that would bring its transmittance T to T_MIN or below."""

COV2D_BLUR = 0.3
"""Added to the diagonal of every projected 2D covariance, in px^2 (low-pass / anti-alias)."""

NEAR = 0.01
"""Gaussians whose camera-space depth z is not greater than NEAR (scene units) are culled."""

FRUSTUM_MARGIN = 0.3
"""The projection's Jacobian clamps x/z and y/z to the image's extent plus this fraction of the half field of
view on each side (gsplat's `lim_x`, `lim_y`: 1.3 half fields of view for a centred principal point); beyond it
the 2D spread of a Gaussian stops growing with its distance from the image, and x, y get no gradient through it."""

TILE = 16
"""Tile edge in pixels for the tiled paths (16 x 16 tiles)."""

SCALE_MAX = 1e15
"""Largest accepted scale (scene units): `rasterize` refuses larger ones. In float64 the
projected covariance of such a Gaussian seen at the near plane with a 1e6-pixel focal length
stays far from overflow (its determinant ~ (1e15 * 1e6 / NEAR)^4 = 1e92); with 1e20 in float32
the covariance overflowed and every geometric gradient became NaN without an error."""
