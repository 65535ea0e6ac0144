"""L_ev's backward is one numba kernel for grey luminances and a colour DAVIS's renders: one
compilation per dtype serves both, and grey equals a one-channel filter of ones."""

from __future__ import annotations

import numpy as np
import pytest

from ebad.kernels import _numba_event as K
from ebad.kernels.losses import _event_adjoint


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_grey_and_cfa_share_one_specialisation(dtype):
    rng = np.random.default_rng(3)
    V, H, W = 4, 19, 23  # a partial band of rows
    g = np.sign(rng.standard_normal((V - 1, H, W))).astype(dtype)
    X = rng.uniform(-0.1, 1, (V, H, W)).astype(dtype)
    grey = _event_adjoint(X, g, 0.37, 1e-3, None)
    F1 = np.ones((H, W, 1), dtype)
    np.testing.assert_array_equal(grey, _event_adjoint(X[..., None], g, 0.37, 1e-3, F1)[..., 0])
    Xc = rng.uniform(-0.1, 1, (V, H, W, 3)).astype(dtype)
    F = np.eye(3, dtype=dtype)[rng.integers(0, 3, (H, W))]
    cfa = _event_adjoint(Xc, g, 0.37, 1e-3, F)
    d = np.zeros((V, H, W))  # the reference: scale (g_{k-1} - g_k) F_d / (X_d + eps), 0 where X_d < 0
    d[1:] += g
    d[:-1] -= g
    ref = np.where(Xc >= 0, 0.37 * d[..., None] * F / (Xc.astype(np.float64) + 1e-3), 0.0)
    np.testing.assert_allclose(cfa, ref, rtol=1e-6 if dtype == np.float32 else 1e-12)
    assert not hasattr(K, "event_backward_cfa")  # one kernel ...
    sigs = [s for s in K.event_backward.signatures if str(s[0].dtype) == np.dtype(dtype).name]
    assert len(sigs) == 1, sigs  # ... compiled once for grey and colour alike
