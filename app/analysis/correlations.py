"""Bubble-diameter correlations for a porous-plate distributor, beside the measured diameter against height
(the Verma et al. 2014 figure). SI units; also reachable as ``app.analysis.bubbles.darton`` / ``werther``."""
from __future__ import annotations

import numpy as np

#: Gravitational acceleration used by the correlations [m/s^2].
G = 9.81
#: Verma et al. (2014) excess gas velocity U - Umf = 0.5 * Umf, Umf = 0.68 m/s [m/s].
UEX_VERMA = 0.5 * 0.68


def darton(H, uex: float = UEX_VERMA):
    """Darton et al. (1977) bubble diameter [m] for a porous plate (no catchment-area term).

    De = 0.54 Uex^0.4 H^0.8 g^-0.2, with H the height above the distributor [m] and Uex = U - Umf
    [m/s] (SI, dimensionally consistent).
    """
    H = np.asarray(H, dtype=float)
    return 0.54 * uex ** 0.4 * H ** 0.8 * G ** -0.2


def werther(H, uex: float = UEX_VERMA):
    """Werther (1978) bubble diameter [m], in the form written in the Verma reference json.

    De = 0.00853 (1 + 27 Uex)^(1/3) (1 + 6.4 H)^1.21 with H [m] and Uex [m/s]. Werther's original
    is in cm: De[cm] = 0.853 (1 + 0.272 Uex[cm/s])^(1/3) (1 + 0.0684 H[cm])^1.21, whose exact SI
    rewrite has 27.2 and 6.84; we keep the json's constants (27, 6.4), those of seed 000's
    figure, so that the curves are comparable with it.
    """
    H = np.asarray(H, dtype=float)
    return 0.00853 * (1.0 + 27.0 * uex) ** (1.0 / 3.0) * (1.0 + 6.4 * H) ** 1.21
