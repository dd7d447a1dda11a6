"""Write the meshes and textures of the multisampling scenes (deterministic).

    python scenes/multisample/make_assets.py

- ``meshes/facets.ply``: 48 triangles, each with its own three vertices and
  colour (face ``r g b``, read by Mitsuba as the ``face_color`` attribute), at
  random depths and orientations in front of the camera of ``polygons.xml``,
  wound to face it.
- ``textures/zoneplate.png``: a 1024 x 1024 zone plate ``0.5 + 0.5 cos(pi k r^2)``
  (k = 96, r = 1 at the image's half width): mapped onto ``bitmap.xml``'s plane
  it reaches 1.5 cycles per *screen* pixel at the frame's edge (3x Nyquist),
  0.19 cycles per texel (well inside the bitmap's own band). Only one quadrant
  (512 x 512, from the centre outwards) is stored: the plate is symmetric in x
  and y, and ``bitmap.xml`` mirrors it (``wrap_mode`` mirror, ``to_uv`` maps the
  plane's uv to [-1, 1]^2), which gives the full plate's texel grid exactly
  (renders are bit-identical to the full 1024^2 bitmap's, bilinear and nearest).
- ``textures/zoneplate_prefiltered.png``: the same zone plate box-filtered to
  one texel per screen pixel (the mean of each 8 x 8 block), the mip level a
  trilinear texture unit would pick for this view; again one quadrant (64 x 64).

The files are committed (about 0.25 MB in all), so the scenes render in a fresh
clone; this script only documents and reproduces them.
- ``textures/checker_prefiltered.png``: the ``checkerboard`` texture of
  ``checker.xml`` (10 degrees rotated, ``$checks`` periods across) box-filtered
  over one screen pixel, one texel per screen pixel, texel centres on pixel
  centres (64 x 64 sub-samples per texel): a lookup at a pixel centre returns
  that pixel's average of the checks (the mip level for this footprint).

PNGs are 8-bit greyscale, read by the scenes with ``raw=true`` (no sRGB decoding).
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
#: Screen pixels across the textured plane in checker.xml (its film width).
SCREEN = 128
#: Checkerboard periods across the plane (checker.xml's default $checks).
CHECKS = 75.3
#: Rotation of the checkerboard's uv (degrees), as in checker.xml.
ANGLE = 10.0


def write_grey_png(path: Path, image: np.ndarray) -> None:
    """An 8-bit greyscale PNG of ``image`` in [0, 1] (rounded, no transfer curve)."""
    data = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
    h, w = data.shape
    raw = b"".join(b"\x00" + data[y].tobytes() for y in range(h))

    def chunk(kind: bytes, payload: bytes) -> bytes:
        return (struct.pack(">I", len(payload)) + kind + payload
                + struct.pack(">I", zlib.crc32(kind + payload) & 0xFFFFFFFF))

    path.parent.mkdir(parents=True, exist_ok=True)
    header = chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 0, 0, 0, 0))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + header + chunk(b"IDAT", zlib.compress(raw, 9))
                     + chunk(b"IEND", b""))


def zone_plate(size: int = 1024, k: float = 96.0) -> np.ndarray:
    c = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    r2 = c[None, :] ** 2 + c[:, None] ** 2
    return 0.5 + 0.5 * np.cos(np.pi * k * r2)


def quadrant(image: np.ndarray) -> np.ndarray:
    """The lower-right quadrant of a centre-symmetric image (rows and columns
    from the centre outwards), which a mirrored lookup extends to the whole."""
    h, w = image.shape
    assert np.allclose(image, image[::-1]) and np.allclose(image, image[:, ::-1]), "not symmetric"
    return image[h // 2:, w // 2:]


def checker(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Mitsuba's ``checkerboard`` (color0 1, color1 0) at uv after its ``to_uv``
    (rotate ``ANGLE`` then scale ``CHECKS``): colour0 where both fractional
    parts are on the same side of 0.5."""
    a = np.radians(ANGLE)
    x = CHECKS * (np.cos(a) * u - np.sin(a) * v)
    y = CHECKS * (np.sin(a) * u + np.cos(a) * v)
    return (((x - np.floor(x)) > 0.5) == ((y - np.floor(y)) > 0.5)).astype(np.float64)


def prefiltered_checker(texels_per_pixel: int = 1, sub: int = 64) -> np.ndarray:
    """Row-major image (row 0 at v = 0) of the checker averaged over a square of
    one screen pixel centred on each texel centre."""
    n = SCREEN * texels_per_pixel
    pixel = 1.0 / SCREEN  # one screen pixel in uv
    centres = (np.arange(n) + 0.5) / n
    offsets = ((np.arange(sub) + 0.5) / sub - 0.5) * pixel
    out = np.zeros((n, n))
    for row in range(n):
        v = centres[row] + offsets[:, None, None]  # (sub, 1, 1)
        u = centres[None, :, None] + offsets[None, None, :]  # (1, n, sub)
        out[row] = checker(np.broadcast_to(u, (sub, n, sub)),
                           np.broadcast_to(v, (sub, n, sub))).mean(axis=(0, 2))
    return out


def facets(count: int = 48, seed: int = 7) -> str:
    """ASCII PLY of ``count`` separate triangles (no shared vertices), each
    wound to face +z (the camera) and with its own colour (face r, g, b)."""
    rng = np.random.default_rng(seed)
    vertices, faces = [], []
    for i in range(count):
        centre = np.array([rng.uniform(-1.1, 1.1), rng.uniform(-1.1, 1.1), rng.uniform(-1, 1)])
        size = rng.uniform(0.25, 0.7)
        tri = [centre + rng.normal(0, size, 3) for _ in range(3)]
        if np.cross(tri[1] - tri[0], tri[2] - tri[0])[2] < 0:
            tri[1], tri[2] = tri[2], tri[1]
        vertices += [" ".join(f"{x:.6f}" for x in v) for v in tri]
        colour = rng.uniform(0.05, 1.0, 3)
        faces.append(f"3 {3 * i} {3 * i + 1} {3 * i + 2} " + " ".join(f"{c:.4f}" for c in colour))
    header = ["ply", "format ascii 1.0", f"element vertex {3 * count}", "property float x",
              "property float y", "property float z", f"element face {count}",
              "property list uchar int vertex_indices", "property float r", "property float g",
              "property float b", "end_header"]
    return "\n".join(header + vertices + faces) + "\n"


def main() -> None:
    (HERE / "meshes").mkdir(exist_ok=True)
    (HERE / "meshes" / "facets.ply").write_text(facets())
    plate = zone_plate()
    block = plate.shape[0] // SCREEN
    small = plate.reshape(SCREEN, block, SCREEN, block).mean(axis=(1, 3))
    # one quadrant each (the plate is symmetric; bitmap.xml mirrors it)
    write_grey_png(HERE / "textures" / "zoneplate.png", quadrant(plate))
    write_grey_png(HERE / "textures" / "zoneplate_prefiltered.png", quadrant(small))
    # the reflectance itself: color1 0.1 + (color0 0.9 - color1) x the share of color0
    write_grey_png(HERE / "textures" / "checker_prefiltered.png",
                   0.1 + 0.8 * prefiltered_checker())


if __name__ == "__main__":
    main()
