"""Multi-layer float32 OpenEXR files (OpenEXR 3.x Python bindings).

Layers and channels
-------------------
``write_exr(path, layers)`` takes a dict ``name -> array`` of float images that
all share one ``(H, W)``:

===============================  ==========================================
layer                            EXR channels
===============================  ==========================================
``"rgb"`` (H, W, 3)              ``R``, ``G``, ``B``
``"rgb"`` (H, W, 4)              ``R``, ``G``, ``B``, ``A``
``name`` (H, W, 3)               ``name.R``, ``name.G``, ``name.B``
``name`` (H, W, 4)               ``name.R``, ``name.G``, ``name.B``, ``name.A``
``name`` (H, W) or (H, W, 1)     ``name.Y``
``"rgb"`` (H, W) or (H, W, 1)    ``Y`` (a luminance image)
===============================  ==========================================

:data:`MAIN_LAYER` (``"rgb"``) is the layer that becomes the unprefixed ``R G B
(A)`` (or ``Y``) channels every EXR viewer shows by default. Layer names must be
non-empty and must not contain ``"."``. Every channel is stored as 32-bit float
(``FLOAT``, never ``HALF``) with lossless ZIP compression, so a float32 array
round-trips bit for bit (NaN and Inf included). Arrays of other dtypes are
converted to float32 first (integers are exact up to 2**24).

``read_exr`` inverts this: unprefixed ``R G B (A)`` become ``"rgb"``, ``name.R
name.G name.B (name.A)`` become an (H, W, 3|4) layer, ``name.Y`` an (H, W)
layer (a 1-channel layer written as (H, W, 1) therefore reads back as (H, W)).
Channels of files written by other tools that fit none of these groups
(``name.X name.Y name.Z`` is also recognised) come back one (H, W) array per
channel, keyed by the full channel name.

Metadata
--------
``metadata`` maps attribute names to ``str``, ``int`` or ``float`` values,
stored as EXR header attributes:

* ``str``   -> ``string`` attribute (UTF-8), read back as ``str``;
* ``int``   -> ``int`` attribute when it fits in a signed 32-bit integer,
  otherwise (EXR has no 64-bit integer attribute) it is stored as its decimal
  ``string`` and reads back as ``str``; ``bool`` is stored as ``int`` 0/1;
* ``float`` -> ``double`` attribute, read back as the same Python ``float``.

NumPy scalars are accepted as their Python equivalents. Names of the standard
EXR attributes (``channels``, ``compression``, ``dataWindow``, ...) are
reserved. ``read_exr`` returns every attribute except the standard structural
ones; attributes of other types written by other tools are returned as the
OpenEXR bindings give them.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping

import numpy as np

from ..core.atomic import ImageIOError, atomic_path, ensure_readable, read_error, write_error

log = logging.getLogger("mcrt.io")

#: Layer whose channels are written without a prefix (``R G B [A]``).
MAIN_LAYER = "rgb"

#: Header attributes that describe the file's structure, not the user's data.
#: They are reserved on write and left out of ``read_exr``'s metadata.
STANDARD_ATTRIBUTES = frozenset({
    "channels", "compression", "dataWindow", "displayWindow", "lineOrder",
    "pixelAspectRatio", "screenWindowCenter", "screenWindowWidth", "tiles", "type",
    "name", "version", "chunkCount", "view", "maxSamplesPerPixel",
})

_INT32_MIN, _INT32_MAX = -(2 ** 31), 2 ** 31 - 1

#: Channel suffix groups recognised by ``read_exr``, in array order.
_GROUPS = (("R", "G", "B", "A"), ("R", "G", "B"), ("X", "Y", "Z"), ("Y",))


def _layer_channels(name: str, array) -> list[tuple[str, np.ndarray]]:
    """Split one layer into (channel name, contiguous float32 (H, W)) pairs."""
    if not isinstance(name, str) or not name or "." in name:
        raise ValueError(f"EXR layer names must be non-empty strings without '.', got {name!r}")
    a = np.asarray(array)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim == 2:  # a luminance image (as a mono variant or luminance film develops)
        suffixes: tuple[str, ...] = ("Y",)
        planes = [a]
    elif a.ndim == 3 and a.shape[2] in (3, 4):
        suffixes = ("R", "G", "B", "A")[: a.shape[2]]
        planes = [a[:, :, c] for c in range(a.shape[2])]
    else:
        raise ValueError(f"EXR layer {name!r} must have shape (H, W), (H, W, 1), (H, W, 3) or "
                         f"(H, W, 4), got {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
        raise ValueError(f"EXR layer {name!r} must hold real numbers, got dtype {a.dtype}")
    prefix = "" if name == MAIN_LAYER else name + "."
    return [(prefix + s, p) for s, p in zip(suffixes, _float32(f"layer {name}", planes),
                                            strict=True)]


def _float32(what: str, planes: list[np.ndarray]) -> list[np.ndarray]:
    """``planes`` as contiguous float32 arrays. Finite values beyond float32's
    range (3.4e38, e.g. a variance of huge radiance) become Inf, said in one
    warning on ``mcrt.io`` naming ``what`` (not numpy's bare RuntimeWarning)."""
    with np.errstate(over="ignore"):
        out = [np.ascontiguousarray(p, dtype=np.float32) for p in planes]
    overflowed = sum(int(np.count_nonzero(np.isinf(o) & np.isfinite(p)))
                     for o, p in zip(out, planes, strict=True)
                     if np.issubdtype(p.dtype, np.floating) and p.dtype.itemsize > 4)
    if overflowed:
        log.warning("EXR %s: %d finite values beyond float32's range (3.4e38) are stored as "
                    "Inf", what, overflowed)
    return out


def _raw_channel(name: str, plane) -> np.ndarray:
    """One channel given by its full name: a contiguous float32 (H, W) plane."""
    if not isinstance(name, str) or not name or name.startswith(".") or name.endswith("."):
        raise ValueError(f"EXR channel names must be non-empty and not start or end with "
                         f"'.', got {name!r}")
    a = np.asarray(plane)
    if a.ndim != 2 or not np.issubdtype(a.dtype, np.number) \
            or np.issubdtype(a.dtype, np.complexfloating):
        raise ValueError(f"EXR channel {name!r} must be a real (H, W) array, got "
                         f"{a.shape} {a.dtype}")
    return _float32(f"channel {name}", [a])[0]


def _header_value(key, value):
    """Convert one metadata value to what the OpenEXR bindings store exactly."""
    if not isinstance(key, str) or not key:
        raise ValueError(f"EXR metadata names must be non-empty strings, got {key!r}")
    if key in STANDARD_ATTRIBUTES:
        raise ValueError(f"EXR metadata name {key!r} is reserved for a standard attribute")
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, int):
        return value if _INT32_MIN <= value <= _INT32_MAX else str(value)
    if isinstance(value, float):
        # A Python float would be stored as a 32-bit 'float' attribute; a 0-d
        # float64 array becomes a 64-bit 'double' attribute.
        return np.array(value, dtype=np.float64)
    raise TypeError(f"EXR metadata {key!r}: values must be str, int or float, "
                    f"got {type(value).__name__}")


def _metadata_value(value):
    """Convert a header value read by the bindings back to a Python value."""
    if isinstance(value, np.ndarray) and value.dtype == np.float64 and value.shape == (1,):
        return float(value[0])  # 'double' attribute
    if isinstance(value, np.generic):
        return value.item()
    return value


def write_exr(path: str | os.PathLike, layers: Mapping[str, np.ndarray],
              metadata: Mapping[str, str | int | float] | None = None,
              channels: Mapping[str, np.ndarray] | None = None) -> None:
    """Write ``layers`` (and ``metadata``) to ``path`` as a float32 EXR, atomically.

    See the module docstring for the channel naming and metadata types. All
    layers must share the same height and width. ``channels`` adds (H, W)
    planes under exactly the given channel names (a film's own labels, such as
    ``Y``, ``X Y Z`` or an AOV integrator's ``nn.X``; dots allowed), written
    before the layers; a name given twice is an error.

    Raises :class:`ValueError` / :class:`TypeError` for malformed layers or
    metadata (programming errors) and :class:`~mcrt.core.atomic.ImageIOError`
    (an :class:`~mcrt.errors.McrtError`) when the file cannot be written (missing
    directory, permission denied, disk full, ...). On any failure a previous
    file at ``path`` is left intact and no temporary file remains.
    """
    import OpenEXR

    if not layers and not channels:
        raise ValueError("write_exr needs at least one layer")
    planes: dict[str, np.ndarray] = {}
    shape: tuple[int, ...] | None = None
    pairs = [(c, c, _raw_channel(c, p)) for c, p in (channels or {}).items()]
    pairs += [(name, c, p) for name, array in layers.items()
              for c, p in _layer_channels(name, array)]
    for name, channel, plane in pairs:
        if shape is None:
            shape = plane.shape
        elif plane.shape != shape:
            raise ValueError(f"EXR layers must share one (H, W): layer {name!r} is "
                             f"{plane.shape}, expected {shape}")
        if channel in planes:
            raise ValueError(f"EXR channel {channel!r} is given twice")
        planes[channel] = plane
    if shape is None or 0 in shape:
        raise ValueError(f"cannot write an empty image of shape {shape}")

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for key, value in (metadata or {}).items():
        header[key] = _header_value(key, value)

    exr = OpenEXR.File(header, planes)
    with atomic_path(path) as tmp:
        try:
            exr.write(tmp)
        except RuntimeError as exc:  # the bindings report I/O failures this way
            raise write_error(path, str(exc).splitlines()[0] if str(exc) else
                              "the OpenEXR library failed to write the file") from exc


def _group_channels(channels: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    by_prefix: dict[str, dict[str, np.ndarray]] = {}
    for full, pixels in channels.items():
        prefix, _, suffix = full.rpartition(".")
        by_prefix.setdefault(prefix, {})[suffix] = pixels
    layers: dict[str, np.ndarray] = {}
    for prefix, members in by_prefix.items():
        name = prefix if prefix else MAIN_LAYER
        group = next((g for g in _GROUPS if set(g) == set(members)), None)
        if group is not None and not (prefix == "" and group == ("X", "Y", "Z")):
            layers[name] = members[group[0]] if len(group) == 1 else \
                np.stack([members[s] for s in group], axis=-1)
        else:
            for suffix, pixels in members.items():
                layers[f"{prefix}.{suffix}" if prefix else suffix] = pixels
    return layers


def read_exr(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """Read an EXR written by :func:`write_exr` (or any scanline/tiled EXR).

    Returns ``(layers, metadata)``: ``layers`` maps layer names to arrays in the
    channels' stored dtype (float32 for files from :func:`write_exr`) with the
    shapes described in the module docstring; ``metadata`` holds the
    non-structural header attributes. Raises
    :class:`~mcrt.core.atomic.ImageIOError` when the file is missing, unreadable or
    not an OpenEXR file.
    """
    import OpenEXR

    ensure_readable(path)
    try:
        exr = OpenEXR.File(os.fspath(path), separate_channels=True)
        header = exr.header()
        channels = {name: np.asarray(ch.pixels) for name, ch in exr.channels().items()}
    except (RuntimeError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise read_error(path, f"not a readable OpenEXR file ({first})") from exc
    metadata = {k: _metadata_value(v) for k, v in header.items()
                if k not in STANDARD_ATTRIBUTES}
    return _group_channels(channels), metadata


def read_exr_header(path: str | os.PathLike) -> dict:
    """The metadata :func:`read_exr` returns, read without the pixels."""
    import OpenEXR

    ensure_readable(path)
    try:
        header = OpenEXR.File(os.fspath(path), header_only=True).header()
    except (RuntimeError, ValueError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise read_error(path, f"not a readable OpenEXR file ({first})") from exc
    return {k: _metadata_value(v) for k, v in header.items() if k not in STANDARD_ATTRIBUTES}


__all__ = ["MAIN_LAYER", "ImageIOError", "read_exr", "read_exr_header", "write_exr"]
