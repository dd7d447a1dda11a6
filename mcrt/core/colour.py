"""Colour every layer shares: linear sRGB <-> CIE XYZ and luminance, in one place.

:data:`SRGB_TO_XYZ` is Mitsuba's matrix (``mi.srgb_to_xyz``, the one ``hdrfilm``
develops ``xyz`` and ``y`` films with): the sRGB primaries and D65 white, its
coefficients as Mitsuba stores them (float32), here in float64. Luminance ``Y``
is its middle row, :data:`LUMINANCE_WEIGHTS` (Rec. 709's 0.2126, 0.7152, 0.0722
to four digits), so a luminance computed here equals the ``Y`` of a film Mitsuba
develops. The adaptive criterion, the metrics and the report viewer (its
JavaScript gets the weights from :mod:`mcrt.analysis.viewer`) all use these.

numpy only: no Mitsuba variant is needed to import it.
"""

from __future__ import annotations

import numpy as np


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


#: Linear sRGB -> CIE XYZ, ``xyz = SRGB_TO_XYZ @ rgb`` (``[row, column]``, float64).
SRGB_TO_XYZ = _read_only(np.array([[0.412453, 0.357580, 0.180423],
                                   [0.212671, 0.715160, 0.072169],
                                   [0.019334, 0.119193, 0.950227]],
                                  dtype=np.float32).astype(np.float64))

#: CIE XYZ -> linear sRGB, the inverse of :data:`SRGB_TO_XYZ`.
XYZ_TO_SRGB = _read_only(np.linalg.inv(SRGB_TO_XYZ))

#: Luminance weights of linear R, G, B: the ``Y`` row of :data:`SRGB_TO_XYZ`.
LUMINANCE_WEIGHTS: tuple[float, float, float] = (
    float(SRGB_TO_XYZ[1, 0]), float(SRGB_TO_XYZ[1, 1]), float(SRGB_TO_XYZ[1, 2]))

__all__ = ["LUMINANCE_WEIGHTS", "SRGB_TO_XYZ", "XYZ_TO_SRGB"]
