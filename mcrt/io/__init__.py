"""Image input/output: float32 multi-layer EXR, sRGB PNG, contact sheets.

All writers are atomic (see :mod:`mcrt.core.atomic`) and report unwritable or
unreadable paths as :class:`ImageIOError`, a :class:`~mcrt.errors.McrtError`.
"""

from __future__ import annotations

from ..core.atomic import ImageIOError, atomic_path
from .exr import MAIN_LAYER, read_exr, read_exr_header, write_exr
from .png import NONFINITE_COLOUR, contact_sheet, encode_srgb, write_contact_sheet, write_png

__all__ = [
    "ImageIOError",
    "MAIN_LAYER",
    "NONFINITE_COLOUR",
    "atomic_path",
    "contact_sheet",
    "encode_srgb",
    "read_exr",
    "read_exr_header",
    "write_contact_sheet",
    "write_exr",
    "write_png",
]
