"""Rec.709 luma weights of linear RGB, the one definition (recon.response re-exports it for the layers
above kernels/)."""
from __future__ import annotations

import numpy as np

LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec.709 luminance weights of linear RGB (R, G, B)
