"""Write the small PLY meshes of ``scenes/hard/degenerate.xml``.

Usage: ``python scenes/hard/make_meshes.py [OUTPUT_DIR]`` (default: the
``meshes/`` folder next to this script). The files are committed; this script
documents exactly what they contain and regenerates them byte for byte
(``tests/core/test_hard_cases.py`` checks that it does).

Every mesh is built on the same unit quad: the square [-1, 1]^2 in the plane
z = 0, facing +z (counter-clockwise seen from +z), as two triangles. The
scenes place it with a ``to_world`` transform.

=============================  ============================================================
file                           content
=============================  ============================================================
``quad.ply``                   the plain quad (the control for the two below)
``quad_zero_area.ply``         the quad plus four zero-area triangles: two with three
                               collinear vertices (one along the quad's diagonal, one
                               sticking out of it), one with two coincident vertices, one
                               with all three vertices equal
``quad_zero_normals.ply``      the quad with per-vertex normals that are all (0, 0, 0)
``quad_nan_color.ply``         the quad with a per-vertex colour (``vertex_color``) that
                               is NaN at one vertex; both triangles use that vertex
=============================  ============================================================

Binary little-endian PLY: Mitsuba's ASCII PLY reader cannot parse ``nan``, and
binary files are exact (no decimal rounding of the float32 values).
"""

from __future__ import annotations

import struct
import sys
from pathlib import Path

import numpy as np

QUAD = [(-1.0, -1.0, 0.0), (1.0, -1.0, 0.0), (1.0, 1.0, 0.0), (-1.0, 1.0, 0.0)]
QUAD_FACES = [(0, 1, 2), (0, 2, 3)]


def ply_bytes(vertices: list[tuple[float, ...]], faces: list[tuple[int, int, int]],
              properties: tuple[str, ...] = ("x", "y", "z")) -> bytes:
    """A binary little-endian PLY: float32 vertex ``properties``, int32 triangles."""
    header = ["ply", "format binary_little_endian 1.0",
              "comment written by mcrt scenes/hard/make_meshes.py",
              f"element vertex {len(vertices)}"]
    header += [f"property float {name}" for name in properties]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices",
               "end_header"]
    out = bytearray(("\n".join(header) + "\n").encode("ascii"))
    for vertex in vertices:
        if len(vertex) != len(properties):
            raise ValueError(f"vertex {vertex} does not match properties {properties}")
        out += np.asarray(vertex, dtype="<f4").tobytes()
    for face in faces:
        out += struct.pack("<B3i", 3, *face)
    return bytes(out)


def meshes() -> dict[str, bytes]:
    """File name -> content of every mesh."""
    nan = float("nan")
    zero_area_vertices = QUAD + [(0.0, 0.0, 0.0), (-0.5, -0.5, 0.0), (1.5, 1.5, 0.0),
                                 (0.5, -0.5, 0.0), (0.5, -0.5, 0.0), (-0.25, 0.5, 0.0)]
    zero_area_faces = QUAD_FACES + [
        (0, 4, 2),   # collinear: along the quad's diagonal (inside it)
        (5, 2, 6),   # collinear: the diagonal's line, reaching outside the quad
        (7, 8, 1),   # two coincident vertices
        (9, 9, 9),   # all three vertices equal
    ]
    return {
        "quad.ply": ply_bytes(QUAD, QUAD_FACES),
        "quad_zero_area.ply": ply_bytes(zero_area_vertices, zero_area_faces),
        "quad_zero_normals.ply": ply_bytes([v + (0.0, 0.0, 0.0) for v in QUAD], QUAD_FACES,
                                           ("x", "y", "z", "nx", "ny", "nz")),
        "quad_nan_color.ply": ply_bytes(
            [v + c for v, c in zip(QUAD, [(0.6, 0.6, 0.6), (0.6, 0.6, 0.6), (nan, nan, nan),
                                          (0.6, 0.6, 0.6)])],
            QUAD_FACES, ("x", "y", "z", "r", "g", "b")),
    }


def write_meshes(directory: Path) -> list[Path]:
    """Write every mesh into ``directory`` (created if needed); return the paths."""
    directory.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, data in meshes().items():
        path = directory / name
        path.write_bytes(data)
        paths.append(path)
    return paths


if __name__ == "__main__":
    target = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent / "meshes"
    for written in write_meshes(target):
        print(f"wrote {written}")
