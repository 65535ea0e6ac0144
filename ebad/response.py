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

- L_blur and L_EDI: the response of the render against the recorded frame and the recorded-domain
  EDI latent (as before);
- L_ev with a c estimated from the frames (``TrainingData.c_recorded``): the log change of the
  *response* of the render against c N, both in the frames' log units; with a configured c
  (``loss.contrast``, the events' own units) the log change of the irradiance itself.

L_ev and L_EDI then hold for every curve of the family E -> E^(gamma_true / gamma) (with the gain),
as they must (events and sharp images do not tell gamma, ``edi.estimate_contrast``), and the one
loss that does tell it decides: L_blur, because blur averages irradiance, not recorded values.
Measured on the tiny synthetic boxes (``make_scene``, 8 frames, 1500 steps; the true curve never
reaches the method, ``tests/ebad/test_response_units.py``): a pure gamma 0.75 is learnt as 0.732
(lr_response 0.3); the realistic sensor's (black 0.04, gain 1.25) as 0.799 at lr_response 0.1
(0.956 in the old units) and near 0.67 at 0.3: the black level, started at 0, is not learnt and
the darks' compressed contrast goes into gamma.

- ``linear``: recorded = irradiance (no parameters; what ebad assumed before).
- ``gamma``: recorded = b + (1 - b) min(g E, 1)^gamma, with black level b, gain g and exponent
  gamma learnt with the scene, starting at the identity (b = 0, g = 1, gamma = 1). Monotone in E
  by construction; ``min(., 1)`` saturates bright parts as a sensor does.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["Response", "RESPONSES", "MAX_BLACK"]

RESPONSES = ("linear", "gamma")
MAX_BLACK = 0.5  # the learnt black level stays in [0, MAX_BLACK)
_TINY = 1e-6  # x^gamma has an infinite slope at 0 for gamma < 1


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

    def values(self) -> dict[str, float]:
        """The curve's black level, gain and exponent."""
        b, g, k = self.raw.detach().tolist()
        return {
            "black": MAX_BLACK * float(torch.sigmoid(torch.tensor(b))),
            "gain": float(torch.exp(torch.tensor(g))),
            "gamma": float(torch.exp(torch.tensor(k))),
        }

    def forward(self, irradiance: Tensor) -> Tensor:  # [..., D] -> [..., D]
        if self.kind == "linear":
            return irradiance
        black = MAX_BLACK * torch.sigmoid(self.raw[0])
        x = (torch.exp(self.raw[1]) * irradiance).clamp(_TINY, 1.0)
        return black + (1 - black) * x ** torch.exp(self.raw[2])
