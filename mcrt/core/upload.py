"""numpy arrays handed to Dr.Jit, without multiplying kernels.

On the LLVM backend Dr.Jit maps a contiguous numpy array's memory instead of
copying it, and a kernel that reads such an input with plain vector loads (not
gathers) is compiled for its alignment: 128-byte aligned, or not. A kernel with
``k`` such inputs thus exists in up to ``2**k`` variants, each compiled the
first time numpy's allocator happens to hand out that combination. Measured
(Dr.Jit 1.5, this module's test): the adaptive reduction kernel with eight
uploaded columns was recompiled in 4-6 of a render's 16 passes, ~0.1 s each.
Uploading from a 128-byte aligned copy always gives the same kernel.
"""

from __future__ import annotations

from typing import Any

import drjit as dr
import numpy as np

#: Alignment Dr.Jit's LLVM backend specialises kernels on.
ALIGNMENT = 128

_DTYPES = {dr.VarType.Bool: np.bool_, dr.VarType.Int32: np.int32, dr.VarType.UInt32: np.uint32,
           dr.VarType.Int64: np.int64, dr.VarType.UInt64: np.uint64,
           dr.VarType.Float32: np.float32, dr.VarType.Float64: np.float64}


def aligned_copy(array: Any, dtype: Any = None) -> np.ndarray:
    """A C-contiguous copy of ``array`` (as ``dtype``) starting at an
    :data:`ALIGNMENT`-byte boundary."""
    array = np.asarray(array, dtype=dtype)
    raw = np.empty(array.nbytes + ALIGNMENT, np.uint8)
    offset = (-raw.ctypes.data) % ALIGNMENT
    out = raw[offset:offset + array.nbytes].view(array.dtype).reshape(array.shape)
    out[...] = array
    return out


def to_device(kind: Any, array: Any) -> Any:
    """``kind`` (a flat Dr.Jit array type, e.g. ``mi.Float64``) holding the
    values of ``array`` (flattened), from an aligned copy (see above)."""
    return kind(aligned_copy(np.ravel(array), _DTYPES[dr.type_v(kind)]))


__all__ = ["ALIGNMENT", "aligned_copy", "to_device"]
