"""The camera's response: from the irradiance the Gaussians render to the value the APS records.

Blur averages irradiance and events see log irradiance, but a real APS records a monotone,
saturating function of irradiance (DESIGN.md). The model therefore renders irradiance, and a
``Response`` maps it to recorded values before L_blur and L_EDI (and for every image a user
sees: test views, deblurred frames); L_ev works on the log of the irradiance itself.

Units of the event loss. Events fire on log irradiance with thresholds c_true; the frames record
R = b + (1 - b) (g E)^gamma. ``edi.estimate_c`` and the EDI latents work on the recorded frames,
where a log change of E shows as about gamma x its value: the c ``prepare`` estimates is in the
frames' log units (gamma x c_true), and the latents are recorded values. Applied to log irradiance
that c forces the render's own contrast down to gamma x the truth, the render then already is the
recorded image and the curve stays at the identity (gamma 0.994 learnt for a true 0.75). So with a
learnt response every loss compares in the domain its target was measured in:

- L_blur: the response of the render against the recorded frame; L_EDI: against the response of
  the irradiance EDI latent (``edi_targets`` below; with mEDI, the recorded-domain latent as before);
- L_ev with a c estimated from the frames (``TrainingData.c_recorded``): the log change of the
  *response* of the render against c N, both in the frames' log units; with a configured c
  (``loss.contrast``, the events' own units) the log change of the irradiance itself.

L_ev then holds for every curve of the family E -> E^(gamma_true / gamma) (with the gain), as it
must (events and sharp images do not tell gamma, ``edi.estimate_contrast``); L_blur tells it, because
blur averages irradiance, not recorded values, and so does L_EDI with irradiance targets (its EDI
integral averages irradiance too).
Measured on the tiny synthetic boxes (``make_scene``, 8 frames, 1500 steps; the true curve never
reaches the method, ``tests/ebad/test_response_units.py``), with L_EDI's targets still in the recorded
domain: a pure gamma 0.75 is learnt as 0.732 (lr_response 0.3); the realistic sensor's (black 0.04,
gain 1.25) as 0.799 at lr_response 0.1 (0.956 in the old units) and near 0.67 at 0.3: the black
level, started at 0, is not learnt and the darks' compressed contrast goes into gamma.

L_EDI's targets in irradiance (``edi_targets``). The sensor integrates irradiance over the exposure
and then applies its response, so EDI holds in irradiance: L_irr(u) = R^-1(B) exp(r_u) with
r_u = c_irr E(u) - log((1/T) integral exp(c_irr E(t)) dt), c_irr = c / gamma for a c estimated from
the frames (the events' own c for a configured one). For R = b + (1 - b) (g E)^gamma the target
R(L_irr(u)) = b + (B - b) exp(gamma r_u): the gain cancels, and it is exact for every such curve
(a recorded-domain EDI latent is not: the mean of E^gamma is not the gamma-th power of the mean).
``prepare`` keeps the events' E(u) and the log mean at a grid of contrast scales s
(``ebad.data.EdiTables``), so the targets follow the learnt curve at every step (detached). Measured
(the boxes above, 1500 steps, seed 0; recorded-domain targets -> irradiance targets): realistic
sensor, lr_response 0.1, gamma 0.793 -> 0.748, deblurred frames 26.37 -> 26.39 dB; pure power law at
0.1, 0.815 -> 0.771, 27.48 -> 27.43 dB; at 0.3, 0.729 -> 0.646 (an overshoot), 27.44 -> 27.42 dB.

- ``linear``: recorded = irradiance (no parameters; what ebad assumed before).
- ``gamma``: recorded = b + (1 - b) min(g E, 1)^gamma, with black level b, gain g and exponent
  gamma learnt with the scene, starting at the identity (b = 0, g = 1, gamma = 1). Monotone in E
  by construction; ``min(., 1)`` saturates bright parts as a sensor does.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["Response", "RESPONSES", "MAX_BLACK", "edi_targets"]

RESPONSES = ("linear", "gamma")
MAX_BLACK = 0.5  # the learnt black level stays in [0, MAX_BLACK)
_TINY = 1e-6  # x^gamma has an infinite slope at 0 for gamma < 1
_MAX_LOG_GAIN = 10.0  # an EDI target's gain over B is at most e^10 (it is clipped to 1 anyway)


class Response(nn.Module):
    """A monotone camera response (see the module docstring); ``kind`` one of ``RESPONSES``."""

    def __init__(self, kind: str = "linear"):
        super().__init__()
        if kind not in RESPONSES:
            raise ValueError(f"response kind must be one of {RESPONSES}, got {kind!r}")
        self.kind = kind
        # raw parameters: black = MAX_BLACK * sigmoid(b) (starts at ~0), gain = exp(g), gamma = exp(k)
        self.raw = nn.Parameter(torch.tensor([-12.0, 0.0, 0.0]), requires_grad=kind != "linear")

    @property
    def learnable(self) -> bool:
        return self.kind != "linear"

    def curve(self) -> tuple[Tensor, Tensor, Tensor]:
        """The curve's black level, gain and exponent as tensors of ``raw`` (differentiable)."""
        return MAX_BLACK * torch.sigmoid(self.raw[0]), torch.exp(self.raw[1]), torch.exp(self.raw[2])

    def values(self) -> dict[str, float]:
        """The curve's black level, gain and exponent."""
        with torch.no_grad():
            black, gain, gamma = self.curve()
        return {"black": float(black), "gain": float(gain), "gamma": float(gamma)}

    def forward(self, irradiance: Tensor) -> Tensor:  # [..., D] -> [..., D]
        if self.kind == "linear":
            return irradiance
        black, gain, gamma = self.curve()
        x = (gain * irradiance).clamp(_TINY, 1.0)
        return black + (1 - black) * x**gamma


def edi_targets(
    response: Response,
    blurry: Tensor,  # [H, W, D] the recorded blurry frame
    e_at: Tensor,  # [U, H, W] the events' log change E(u) at the target instants (units of the prepared c)
    logmean: Tensor,  # [K, H, W] log((1/T) integral exp(s E(t)) dt) at the scales ``scales``
    scales: Tensor,  # [K] increasing, evenly spaced (or one scale, 1)
    c_recorded: bool,
    saturation: float,
) -> Tensor:  # [U, H, W, D]
    """L_EDI's targets R(L_irr(u)) = b + (B - b) exp(gamma r_u) for ``response``'s current curve (the
    module docstring), in [0, 1]: r_u = s E(u) - logmean(s) with s = 1 / gamma when the c is the
    frames' (``c_recorded``), else 1; logmean is interpolated linearly between the scales (held at
    the ends). Pixels with B >= ``saturation`` in any channel keep B (as ``edi.deblur`` does).
    Differentiable in the response's parameters (``EdiTables.targets`` detaches them)."""
    if response.kind == "linear":
        black, gamma = blurry.new_zeros(()), blurry.new_ones(())
    else:
        black, _, gamma = response.curve()
    s = 1.0 / gamma if c_recorded else torch.ones_like(gamma)
    K = int(scales.shape[0])
    if K == 1:
        lm = logmean[0]
    else:
        h = scales[1] - scales[0]
        x = ((s - scales[0]) / h).clamp(0.0, K - 1)
        i = int(x.detach().floor().clamp(max=K - 2))
        w = x - i
        lm = (1 - w) * logmean[i] + w * logmean[i + 1]
    expo = (gamma * (s * e_at - lm)).clamp(max=_MAX_LOG_GAIN)  # [U, H, W]
    target = black + (blurry - black).clamp_min(0.0)[None] * torch.exp(expo)[..., None]
    saturated = (blurry >= saturation).any(-1)[..., None]  # [H, W, 1]
    return torch.where(saturated, blurry[None], target).clamp(0.0, 1.0)
