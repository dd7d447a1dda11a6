"""8-bit sRGB PNGs of linear renders, and labelled contact sheets.

Display rule (one rule, used by every function here)
----------------------------------------------------
Given linear RGB values ``x`` and an ``exposure`` in stops:

1. **Non-finite pixels** - a pixel with any NaN, +Inf or -Inf component is
   drawn in :data:`NONFINITE_COLOUR`, opaque magenta ``(255, 0, 255)``, so
   numerical bugs are impossible to miss. (It is never clipped or mapped to 0.)
2. **Exposure** - the other pixels are scaled by ``2 ** exposure``.
3. **Clipping** - each channel is clipped to ``[0, 1]`` on its own: values above
   1 become 1 (full white for a grey pixel; a saturated colour keeps its
   clipped hue), negative values become 0. No tone mapping is applied.
4. **Encoding** - the sRGB transfer function (IEC 61966-2-1, :func:`srgb_transfer`:
   ``12.92 x`` up to ``x = 0.0031308``, ``1.055 x^(1/2.4) - 0.055`` above, in
   float64 exactly as colour-science's ``cctf_encoding(..., function="sRGB")``
   computes it, which the tests check), then ``floor(255 v + 0.5)`` to ``uint8``.

So linear 0 -> 0, 0.5 -> 188, 1 -> 255 and 2 -> 255.

Accepted inputs are float arrays of shape (H, W, 3), (H, W, 4) (alpha is
ignored, no compositing), (H, W) or (H, W, 1) (grey, replicated to RGB), and
anything ``numpy.asarray`` converts to those (``mi.TensorXf``, ``mi.Bitmap``).
"""

from __future__ import annotations

import functools
import math
import os
import struct
import zlib
from collections.abc import Iterator, Mapping, Sequence

import numpy as np

from ..core.atomic import atomic_path

#: Colour of pixels with a NaN or infinite component.
NONFINITE_COLOUR = (255, 0, 255)


def _as_rgb(rgb_linear) -> np.ndarray:
    a = np.asarray(rgb_linear)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[:, :, 0]
    if a.ndim == 2:
        a = np.repeat(a[:, :, None], 3, axis=2)
    elif a.ndim == 3 and a.shape[2] == 4:
        a = a[:, :, :3]
    elif not (a.ndim == 3 and a.shape[2] == 3):
        raise ValueError(f"expected an image of shape (H, W), (H, W, 1), (H, W, 3) or "
                         f"(H, W, 4), got {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
        raise ValueError(f"expected real pixel values, got dtype {a.dtype}")
    return a


#: End of the linear segment of the sRGB encoding (IEC 61966-2-1).
SRGB_LINEAR_LIMIT = 0.0031308


def srgb_transfer(x: np.ndarray) -> np.ndarray:
    """The sRGB transfer function (IEC 61966-2-1 inverse EOTF) of linear values in [0, 1].

    ``12.92 x`` for ``x <= 0.0031308``, else ``1.055 x^(1/2.4) - 0.055``; float64.
    (Replaces ``colour.cctf_encoding(x, function="sRGB")``, whose import alone
    takes longer than most renders' set-up; same operations, same bits.)
    """
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= SRGB_LINEAR_LIMIT, x * 12.92, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def _code(x: np.ndarray) -> np.ndarray:
    """The display rule's 8-bit code of linear values already clipped to [0, 1]."""
    return np.floor(np.clip(srgb_transfer(x), 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


@functools.cache
def code_thresholds() -> np.ndarray:
    """For k = 1..255, the smallest float64 ``x`` in [0, 1] whose code is >= k.

    The code is a non-decreasing function of ``x``, so the code of any ``x`` is
    the number of thresholds <= ``x`` (``np.searchsorted``): the same bytes as
    evaluating the transfer function per pixel, at a fraction of the time and
    memory. Found by bisection on the float64 bit patterns (ordered like the
    values for non-negative floats), 64 steps per threshold.
    """
    lo = np.zeros(255, np.int64)  # bits of 0.0: code 0
    hi = np.full(255, np.float64(1.0).view(np.int64))  # bits of 1.0: code 255
    want = np.arange(1, 256)
    for _ in range(64):
        mid = (lo + hi) // 2
        high_enough = _code(mid.view(np.float64)) >= want
        hi = np.where(high_enough, mid, hi)
        lo = np.where(high_enough, lo, mid)
    return hi.view(np.float64)


#: Rows encoded at a time: the encoder's memory stays bounded for any image size.
ROWS_PER_CHUNK = 256


@functools.cache
def _float32_table() -> tuple[np.ndarray, np.ndarray] | None:
    """Codes of float32 values in [0, 1] by the top 16 bits of their bit pattern.

    For bucket ``b`` (the floats whose bits are ``b << 16 .. b << 16 | 0xFFFF``):
    ``base[b]``, the code of its smallest value, and ``step[b]``, the smallest
    float32 of the bucket whose code is ``base[b] + 1`` (or +inf). The code of
    any float32 ``x`` in [0, 1] is then ``base[b] + (x >= step[b])``: exact, as
    long as no bucket spans two thresholds, which is checked here (None if it did).
    """
    thresholds = code_thresholds()
    t32 = thresholds.astype(np.float32)
    t32 = np.where(t32.astype(np.float64) < thresholds, np.nextafter(t32, np.float32(2)), t32)
    top = np.float32(1.0).view(np.uint32) >> 16
    first = (np.arange(top + 1, dtype=np.uint32) << 16).view(np.float32)
    last = (np.minimum((np.arange(top + 1, dtype=np.uint32) << 16) | 0xFFFF,
                       np.float32(1.0).view(np.uint32))).view(np.float32)
    base = np.searchsorted(thresholds, first.astype(np.float64), side="right")
    if np.any(np.searchsorted(thresholds, last.astype(np.float64), side="right") > base + 1):
        return None
    step = np.append(t32, np.float32(np.inf))[base]
    return base.astype(np.uint8), step


def _encode_rows(x: np.ndarray, thresholds: np.ndarray, scale: float) -> np.ndarray:
    """The display rule for a block of rows (any float dtype)."""
    table = _float32_table() if x.dtype == np.float32 and scale == 1.0 else None
    bad = ~np.all(np.isfinite(x), axis=2)
    if table is not None:  # float32 at exposure 0: exact by the table, no float64 copy
        x = np.clip(np.where(bad[..., None], np.float32(0), x), np.float32(0), np.float32(1))
        bucket = (x.view(np.uint32) & 0x7FFFFFFF) >> 16  # (-0.0 is bucket 0)
        base, step = table
        block = base[bucket] + (x >= step[bucket]).astype(np.uint8)
    else:
        y = x.astype(np.float64)
        y[bad] = 0.0
        y = np.clip(y * scale, 0.0, 1.0)
        block = np.searchsorted(thresholds, y, side="right").astype(np.uint8)
    block[bad] = NONFINITE_COLOUR
    return block


def encode_srgb(rgb_linear, exposure: float = 0.0) -> np.ndarray:
    """Encode linear RGB to an ``(H, W, 3)`` ``uint8`` sRGB image.

    Applies the module's display rule: non-finite pixels -> magenta, scale by
    ``2 ** exposure``, clip each channel to [0, 1], sRGB transfer function,
    round to 8 bits (through :func:`code_thresholds`, in chunks of rows).
    """
    if not math.isfinite(exposure):
        raise ValueError(f"exposure must be a finite number of stops, got {exposure!r}")
    a = _as_rgb(rgb_linear)
    out = np.empty(a.shape, np.uint8)
    thresholds, scale = code_thresholds(), 2.0 ** exposure
    for top in range(0, a.shape[0], ROWS_PER_CHUNK):
        out[top:top + ROWS_PER_CHUNK] = _encode_rows(a[top:top + ROWS_PER_CHUNK], thresholds,
                                                      scale)
    return out


def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + \
        struct.pack(">I", zlib.crc32(data, zlib.crc32(kind)))


def _text_chunk(keyword: str, text: str) -> bytes:
    """An uncompressed iTXt chunk (UTF-8 text: paths need not be Latin-1); the
    keyword is 1-79 Latin-1 characters."""
    key = keyword.encode("latin-1")
    if not 1 <= len(key) <= 79:
        raise ValueError(f"a PNG text keyword has 1 to 79 characters, got {keyword!r}")
    return _chunk(b"iTXt", key + b"\0\0\0\0\0" + text.encode("utf-8"))


def _png_chunks(rgb8: np.ndarray, text: Mapping[str, str] | None = None) -> Iterator[bytes]:
    """An 8-bit RGB image as PNG (ISO/IEC 15948): signature, IHDR, an iTXt chunk
    per ``text`` entry, IDAT chunks (rows with filter type 0, deflated at level 1
    in bounded pieces), IEND."""
    height, width = rgb8.shape[:2]
    yield b"\x89PNG\r\n\x1a\n"
    yield _chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
    for keyword, value in (text or {}).items():
        yield _text_chunk(keyword, value)
    deflate = zlib.compressobj(1)  # fast: a preview, not an archive
    rows = np.zeros((min(ROWS_PER_CHUNK, height), 1 + 3 * width), np.uint8)  # byte 0: filter 0
    for top in range(0, height, ROWS_PER_CHUNK):
        block = rgb8[top:top + ROWS_PER_CHUNK]
        rows[:len(block), 1:] = block.reshape(len(block), -1)
        data = deflate.compress(rows[:len(block)].tobytes())
        if data:
            yield _chunk(b"IDAT", data)
    yield _chunk(b"IDAT", deflate.flush())
    yield _chunk(b"IEND", b"")


def _write_rgb8(path, rgb8: np.ndarray, text: Mapping[str, str] | None = None) -> None:
    """Write an ``(H, W, 3)`` uint8 image as PNG to ``path`` atomically."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        for piece in _png_chunks(np.ascontiguousarray(rgb8, dtype=np.uint8), text):
            f.write(piece)


def _save_png(path, image, text: Mapping[str, str] | None = None) -> None:
    """Write a PIL image as PNG to ``path`` atomically, with ``text`` as iTXt chunks."""
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    for keyword, value in (text or {}).items():
        info.add_itxt(keyword, value)
    with atomic_path(path) as tmp:  # fast; a preview, not an archive
        image.save(tmp, format="PNG", compress_level=1, pnginfo=info)


def write_png(path: str | os.PathLike, rgb_linear, exposure: float = 0.0,
              text: Mapping[str, str] | None = None) -> None:
    """Write linear RGB as an 8-bit sRGB PNG (display rule above), atomically;
    ``text`` (keyword: value) goes into iTXt chunks, e.g.
    :func:`mcrt.core.provenance.png_text`'s command and software.

    Raises :class:`~mcrt.core.atomic.ImageIOError` (an
    :class:`~mcrt.errors.McrtError`) when ``path`` cannot be written; a previous
    file at ``path`` is then left intact.
    """
    _write_rgb8(path, encode_srgb(rgb_linear, exposure), text)


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError, ImportError):  # old Pillow or no FreeType: bitmap font
        return ImageFont.load_default()


def contact_sheet(images: Sequence[tuple[str, object]], columns: int | None = None, *,
                  exposure: float = 0.0, zoom: int = 1, title: str | None = None,
                  font_size: int = 14, padding: int = 8):
    """Build a labelled grid of images and return it as a ``PIL.Image`` (RGB).

    ``images`` is a sequence of ``(label, rgb_linear)`` (labels may span several
    lines, separated by ``"\\n"``); each image is encoded
    with :func:`encode_srgb` (same ``exposure`` for all) and enlarged by the
    integer ``zoom`` with nearest-neighbour replication, so every rendered pixel
    stays a sharp block of identical pixels (no resampling that would blur
    noise or add its own moire). Images may differ in size; each sits in the
    top-left of a cell sized for the largest image and the widest label.
    ``columns`` defaults to ``ceil(sqrt(len(images)))``.
    """
    from PIL import Image, ImageDraw

    if not images:
        raise ValueError("a contact sheet needs at least one image")
    if not isinstance(zoom, int) or zoom < 1:
        raise ValueError(f"zoom must be a positive integer, got {zoom!r}")
    n = len(images)
    columns = columns or math.ceil(math.sqrt(n))
    if columns < 1:
        raise ValueError(f"columns must be positive, got {columns!r}")
    rows = math.ceil(n / columns)

    tiles = []
    for label, rgb in images:
        u8 = encode_srgb(rgb, exposure)
        if zoom > 1:
            u8 = np.repeat(np.repeat(u8, zoom, axis=0), zoom, axis=1)
        tiles.append((str(label), Image.fromarray(u8, mode="RGB")))

    font = _font(font_size)
    measure = ImageDraw.Draw(Image.new("RGB", (1, 1)))

    def text_size(text: str) -> tuple[int, int]:
        """Extent of ``text`` drawn at (0, 0), multi-line labels included."""
        if not text:
            return 0, 0
        _, _, right, bottom = measure.textbbox((0, 0), text, font=font)
        return math.ceil(right), math.ceil(bottom)  # ints already for Pillow's fonts

    label_h = max(text_size(lbl)[1] for lbl, _ in tiles)
    label_h = max(label_h, font_size) + padding // 2
    cell_w = max(max(t.width for _, t in tiles), max(text_size(lbl)[0] for lbl, _ in tiles))
    cell_h = label_h + max(t.height for _, t in tiles)
    title_h = text_size(title)[1] + padding if title else 0

    width = padding + columns * (cell_w + padding)
    height = padding + title_h + rows * (cell_h + padding)
    sheet = Image.new("RGB", (width, height), (32, 32, 32))
    draw = ImageDraw.Draw(sheet)
    if title:
        draw.text((padding, padding), title, fill=(235, 235, 235), font=font)
    for i, (label, tile) in enumerate(tiles):
        r, c = divmod(i, columns)
        x = padding + c * (cell_w + padding)
        y = padding + title_h + r * (cell_h + padding)
        draw.text((x, y), label, fill=(220, 220, 220), font=font)
        sheet.paste(tile, (x, y + label_h))
    return sheet


def write_contact_sheet(path: str | os.PathLike, images: Sequence[tuple[str, object]],
                        columns: int | None = None, *, exposure: float = 0.0, zoom: int = 1,
                        title: str | None = None, font_size: int = 14,
                        text: Mapping[str, str] | None = None) -> None:
    """Write :func:`contact_sheet` ``(images, columns, ...)`` as a PNG, atomically
    (``text`` as for :func:`write_png`)."""
    _save_png(path, contact_sheet(images, columns, exposure=exposure, zoom=zoom, title=title,
                                  font_size=font_size), text)


__all__ = ["NONFINITE_COLOUR", "SRGB_LINEAR_LIMIT", "contact_sheet", "encode_srgb",
           "srgb_transfer", "write_contact_sheet", "write_png"]
