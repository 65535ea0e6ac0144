"""The seeded synthetic ground truth (edi.moving_texture)."""

import numpy as np
import pytest

from edi import LOG_EPS, InputError, moving_texture, seconds_to_us


def test_moving_texture_lead_shifts_the_exposures_and_keeps_the_sensor_running():
    a = moving_texture(num_frames=2, seed=1, c=0.2)
    b = moving_texture(num_frames=2, seed=1, c=0.2, lead=0.03)
    np.testing.assert_allclose(b.exposures, a.exposures + 0.03)
    assert b.events.t[-1] > a.events.t[-1] and (b.events.t < seconds_to_us(0.03)).any()  # events before frame 0
    for bad in (-0.01, float("nan")):
        with pytest.raises(InputError, match="lead"):
            moving_texture(num_frames=1, lead=bad)


def _image(tex, t):
    """[H, W, D] the texture at time t, each pixel the sum of its sines."""
    out = np.zeros((tex.height, tex.width, tex.channels))
    for y in range(tex.height):
        for x in range(tex.width):
            u, v = x + 0.5 - tex.velocity[0] * t, y + 0.5 - tex.velocity[1] * t
            for d in range(tex.channels):
                f = np.sum(
                    tex.amps * np.sin(2 * np.pi * (tex.freqs[:, 0] * u + tex.freqs[:, 1] * v) + tex.phases[:, d])
                )
                out[y, x, d] = tex.lo + (tex.hi - tex.lo) / (1.0 + np.exp(-tex.gain * f))
    return out


def _reference(seq, step_us=50):
    """The generator written plainly, from ``seq``'s own texture and thresholds: the images stepped
    one time after another; an event per crossed threshold, a step's up events before its down
    events, each in (y, x) order; each frame the mean of the images of the steps in its exposure."""
    H, W = seq.texture.height, seq.texture.width
    c_pos, c_neg = seq.c
    t_end = seconds_to_us(seq.exposures[-1, 1])
    ref = np.log(_image(seq.texture, 0.0).mean(-1) + LOG_EPS)
    events, images = [], {}
    for tj in range(0, t_end + step_us, step_us):
        images[tj] = _image(seq.texture, tj * 1e-6)
        d = np.log(images[tj].mean(-1) + LOG_EPS) - ref
        n_up, n_dn = np.floor(np.maximum(d, 0) / c_pos), np.floor(np.maximum(-d, 0) / c_neg)
        ref = ref + n_up * c_pos - n_dn * c_neg
        for n, pol in ((n_up, 1), (n_dn, -1)):
            events += [(tj, x, y, pol) for y in range(H) for x in range(W) for _ in range(int(n[y, x]))]
    frames = [
        np.mean([im for tj, im in images.items() if seconds_to_us(a) <= tj < seconds_to_us(b)], 0)
        for a, b in seq.exposures
    ]
    return np.array(events).reshape(-1, 4), np.stack(frames)


def test_moving_texture_matches_the_generator_written_plainly():
    """The texture is rendered many instants at once (products over the waves: ``Texture.render_many``)
    and the events are gathered after the walk: the same events in the same order, and the same
    frames to rounding, as the plain per-pixel, per-step generator."""
    kw = dict(height=5, width=7, num_frames=2, exposure=0.004, period=0.006, seed=3, channels=3)
    s = moving_texture(c=(0.15, 0.25), **kw)
    want_ev, want_frames = _reference(s)
    got = np.stack([s.events.t, s.events.x, s.events.y, s.events.p], 1)
    assert len(want_ev) > 50 and set(want_ev[:, 3]) == {-1, 1}  # something to compare, both polarities
    np.testing.assert_array_equal(got, want_ev)
    np.testing.assert_allclose(s.frames, want_frames, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.sharp(0.0037), _image(s.texture, 0.0037), rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    "kw",
    [
        {"num_frames": 2, "seed": 0, "c": 0.2},
        {"num_frames": 3, "seed": 4, "c": (0.15, 0.3), "sigma_c": 0.03, "lead": 0.02},
        {"num_frames": 1, "seed": 2, "c": 0.1, "channels": 3, "cfa": "GRBG", "sigma_c": 0.05},
    ],
)
def test_the_compiled_threshold_loop_gives_the_numpy_loop_s_events_bit_for_bit(kw, monkeypatch):
    # the events every estimator test pins its figures on: the compiled loop (_fire) must not move one of them
    import importlib

    mt = importlib.import_module("edi.moving_texture")  # the module (edi.moving_texture is also the function)
    fast = moving_texture(**kw)
    monkeypatch.setattr(mt, "_fire", mt._fire_reference)
    slow = moving_texture(**kw)
    assert len(fast.events) > 1000
    for name in ("t", "x", "y", "p"):
        np.testing.assert_array_equal(getattr(fast.events, name), getattr(slow.events, name))
    np.testing.assert_array_equal(fast.frames, slow.frames)
