"""Image error metrics as plain functions of (image, reference) numpy arrays.

All metrics work on linear radiance, per channel, and average over pixels and
channels; they are computed in float64 whatever the input precision.
"""

from __future__ import annotations

import numpy as np

#: Default epsilon of :func:`rel_mse`: keeps dark pixels from dominating.
REL_MSE_EPSILON = 1e-2


def _pair(image: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    image = np.asarray(image, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    if image.shape != reference.shape:
        raise ValueError(f"image shape {image.shape} differs from reference {reference.shape}")
    return image, reference


def mse(image: np.ndarray, reference: np.ndarray) -> float:
    """Mean squared error ``mean((image - reference)^2)``."""
    image, reference = _pair(image, reference)
    return float(np.mean((image - reference) ** 2))


def rel_mse(image: np.ndarray, reference: np.ndarray, epsilon: float = REL_MSE_EPSILON) -> float:
    """Relative MSE ``mean((image - reference)^2 / (reference^2 + epsilon))``.

    ``epsilon`` (default 0.01, i.e. a reference value of 0.1) keeps black pixels
    from dividing by zero and dominating the average.
    """
    image, reference = _pair(image, reference)
    return float(np.mean((image - reference) ** 2 / (reference ** 2 + epsilon)))
