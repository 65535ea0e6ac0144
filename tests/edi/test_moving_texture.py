"""The seeded synthetic ground truth (edi.moving_texture)."""

import numpy as np
import pytest

from edi import InputError, moving_texture, seconds_to_us


def test_moving_texture_lead_shifts_the_exposures_and_keeps_the_sensor_running():
    a = moving_texture(num_frames=2, seed=1, c=0.2)
    b = moving_texture(num_frames=2, seed=1, c=0.2, lead=0.03)
    np.testing.assert_allclose(b.exposures, a.exposures + 0.03)
    assert b.events.t[-1] > a.events.t[-1] and (b.events.t < seconds_to_us(0.03)).any()  # events before frame 0
    for bad in (-0.01, float("nan")):
        with pytest.raises(InputError, match="lead"):
            moving_texture(num_frames=1, lead=bad)
