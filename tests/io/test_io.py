"""Tests of mcrt.io: float32 EXR layers, atomic writes, sRGB PNGs, contact sheets."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import OpenEXR
import pytest
from PIL import Image

from mcrt.errors import McrtError
from mcrt.io import (
    NONFINITE_COLOUR,
    ImageIOError,
    atomic_path,
    contact_sheet,
    encode_srgb,
    read_exr,
    write_contact_sheet,
    write_exr,
    write_png,
)
from mcrt.io.png import SRGB_LINEAR_LIMIT, srgb_transfer

H, W = 7, 11


def _bits(a: np.ndarray) -> np.ndarray:
    assert a.dtype == np.float32
    return a.view(np.uint32)


@pytest.fixture
def layers():
    rng = np.random.default_rng(1)
    rgb = (rng.standard_normal((H, W, 3)) * 10.0 ** rng.integers(-30, 30, (H, W, 3))).astype(
        np.float32)
    # Values a lossy or half-float path would change.
    rgb[0, 0] = [np.nan, np.inf, -np.inf]
    rgb[0, 1] = [-0.0, np.float32(1e-45), np.finfo(np.float32).max]
    rgb[0, 2] = [1.0 + 2.0 ** -23, 65505.0, 1e-8]
    return {
        "rgb": rgb,
        "variance": rng.random((H, W, 3), dtype=np.float32) * 1e4,
        "spp": rng.integers(1, 2 ** 20, (H, W)).astype(np.float32),
        "albedo": rng.random((H, W, 4), dtype=np.float32),
    }


METADATA = {
    "scene": "cornell_box.xml",
    "sampler": "jittered",
    "spp": 64,
    "negative": -(2 ** 31),
    "seed64": 2 ** 40,          # beyond int32: stored as a string
    "exposure": 0.1,            # needs a double to round-trip
    "tiny": 5e-324,
    "flag": True,
    "unicode": "µ-σ ✓",
    "empty": "",
}


# ---------------------------------------------------------------------- EXR
def test_exr_round_trip_is_bit_exact(tmp_path, layers):
    path = tmp_path / "image.exr"
    write_exr(path, layers, METADATA)
    got, meta = read_exr(path)

    assert set(got) == set(layers)
    for name, array in layers.items():
        assert got[name].dtype == np.float32
        assert got[name].shape == array.shape
        np.testing.assert_array_equal(_bits(got[name]), _bits(array))

    expected = dict(METADATA, seed64=str(2 ** 40), flag=1)
    assert meta == expected
    assert type(meta["exposure"]) is float and type(meta["spp"]) is int


def test_exr_channel_names_and_float32_storage(tmp_path, layers):
    path = tmp_path / "image.exr"
    write_exr(str(path), layers)
    exr = OpenEXR.File(str(path), separate_channels=True)
    channels = exr.channels()
    assert set(channels) == {
        "R", "G", "B",
        "variance.R", "variance.G", "variance.B",
        "spp.Y",
        "albedo.R", "albedo.G", "albedo.B", "albedo.A",
    }
    assert all(c.type() == OpenEXR.FLOAT for c in channels.values())
    np.testing.assert_array_equal(channels["G"].pixels, layers["rgb"][:, :, 1])
    np.testing.assert_array_equal(channels["spp.Y"].pixels, layers["spp"])


def test_exr_rgba_main_layer_and_conversions(tmp_path):
    rgba = np.random.default_rng(2).random((H, W, 4))          # float64 in
    single = np.arange(H * W, dtype=np.int32).reshape(H, W, 1)  # (H, W, 1) int in
    path = tmp_path / "rgba.exr"
    write_exr(path, {"rgb": rgba, "count": single})
    got, meta = read_exr(path)
    assert meta == {}
    np.testing.assert_array_equal(got["rgb"], rgba.astype(np.float32))
    assert got["count"].shape == (H, W)
    np.testing.assert_array_equal(got["count"], single[:, :, 0].astype(np.float32))
    assert set(OpenEXR.File(str(path), separate_channels=True).channels()) == {
        "R", "G", "B", "A", "count.Y"}


def test_read_exr_of_a_file_written_by_mitsuba(tmp_path):
    import mitsuba as mi

    rgb = np.random.default_rng(3).random((H, W, 3), dtype=np.float32)
    path = tmp_path / "mitsuba.exr"
    mi.Bitmap(rgb, mi.Bitmap.PixelFormat.RGB).write(str(path))
    got, _ = read_exr(path)
    np.testing.assert_array_equal(got["rgb"], rgb)


def test_a_luminance_main_layer_is_the_unprefixed_y_channel(tmp_path):
    """A monochrome render (llvm_ad_mono, luminance films) writes one channel, Y,
    as Mitsuba labels it, and reads back as the main layer."""
    import OpenEXR

    y = np.arange(H * W, dtype=np.float32).reshape(H, W)
    write_exr(tmp_path / "y.exr", {"rgb": y})
    assert list(OpenEXR.File(str(tmp_path / "y.exr")).channels()) == ["Y"]
    layers, _ = read_exr(tmp_path / "y.exr")
    np.testing.assert_array_equal(layers["rgb"], y)


@pytest.mark.parametrize("bad_layers, error", [
    ({}, ValueError),
    ({"rgb": np.zeros((H, W, 2))}, ValueError),                   # main layer: 1, 3 or 4 ch
    ({"a.b": np.zeros((H, W))}, ValueError),                      # '.' in a layer name
    ({"x": np.zeros((H, W, 2))}, ValueError),                     # 2 channels
    ({"x": np.zeros((H, W)), "y": np.zeros((H, W + 1))}, ValueError),  # size mismatch
    ({"x": np.zeros((0, W))}, ValueError),
])
def test_write_exr_rejects_malformed_layers(tmp_path, bad_layers, error):
    with pytest.raises(error):
        write_exr(tmp_path / "bad.exr", bad_layers)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("metadata, error", [
    ({"channels": "x"}, ValueError),       # reserved standard attribute
    ({"": 1}, ValueError),
    ({"list": [1, 2]}, TypeError),
    ({"none": None}, TypeError),
])
def test_write_exr_rejects_bad_metadata(tmp_path, metadata, error):
    with pytest.raises(error):
        write_exr(tmp_path / "bad.exr", {"y": np.zeros((2, 2))}, metadata)


def test_exr_numpy_scalar_metadata(tmp_path):
    path = tmp_path / "m.exr"
    write_exr(path, {"y": np.zeros((2, 2))}, {"i": np.int64(7), "f": np.float32(0.5)})
    assert read_exr(path)[1] == {"i": 7, "f": 0.5}


# ------------------------------------------------------------ atomic writes
def _only_file(directory, name):
    """The directory holds exactly ``name``: no temporary files are left."""
    assert sorted(p.name for p in directory.iterdir()) == [name]


def test_exr_failure_mid_write_keeps_previous_file(tmp_path, layers, monkeypatch):
    path = tmp_path / "image.exr"
    write_exr(path, layers, {"generation": 1})
    before = path.read_bytes()

    def crash(self, filename):
        with open(filename, "wb") as f:   # a truncated, half-written file
            f.write(before[: len(before) // 2])
        raise KeyboardInterrupt  # not an OSError: must propagate unchanged

    monkeypatch.setattr(OpenEXR.File, "write", crash)
    with pytest.raises(KeyboardInterrupt):
        write_exr(path, {"rgb": np.zeros((H, W, 3))}, {"generation": 2})
    assert path.read_bytes() == before
    _only_file(tmp_path, "image.exr")

    def io_failure(self, filename):
        with open(filename, "wb") as f:
            f.write(b"\0" * 10)
        raise RuntimeError("Unable to write 'x': No space left on device")

    monkeypatch.setattr(OpenEXR.File, "write", io_failure)
    with pytest.raises(ImageIOError, match="cannot write") as info:
        write_exr(path, {"rgb": np.zeros((H, W, 3))})
    assert "\n" not in str(info.value)
    assert path.read_bytes() == before
    _only_file(tmp_path, "image.exr")

    monkeypatch.undo()
    _, meta = read_exr(path)
    assert meta == {"generation": 1}


def test_failure_at_rename_keeps_previous_file(tmp_path, monkeypatch):
    import mcrt.core.atomic as atomic

    path = tmp_path / "image.png"
    write_png(path, np.full((4, 4, 3), 0.5))
    before = path.read_bytes()

    def refuse(src, dst):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(atomic.os, "replace", refuse)
    with pytest.raises(ImageIOError, match="permission denied"):
        write_png(path, np.zeros((4, 4, 3)))
    assert path.read_bytes() == before
    _only_file(tmp_path, "image.png")


def test_png_failure_mid_write_keeps_previous_file(tmp_path, monkeypatch):
    path = tmp_path / "image.png"
    write_png(path, np.full((4, 4, 3), 0.5))
    before = path.read_bytes()

    import mcrt.io.png as png_module

    def crash(rgb8, text=None):  # the disk fills after the first bytes
        yield b"\x89PNG half"
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(png_module, "_png_chunks", crash)
    with pytest.raises(ImageIOError, match="no space left on device"):
        write_png(path, np.zeros((4, 4, 3)))
    assert path.read_bytes() == before
    _only_file(tmp_path, "image.png")


def test_atomic_path_success_and_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        target = tmp_path / "out.bin"
        with atomic_path(target) as tmp:
            assert os.path.dirname(tmp) == str(tmp_path)
            assert os.path.basename(tmp).startswith(".out.bin.")
            assert not tmp.endswith(".bin")  # globs for the extension never see it
            with open(tmp, "wb") as f:
                f.write(b"new")
            assert not target.exists()
        assert target.read_bytes() == b"new"
        assert target.stat().st_mode & 0o777 == 0o644
        _only_file(tmp_path, "out.bin")
    finally:
        os.umask(old)


def test_atomic_path_removes_temp_file_on_error(tmp_path):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    with pytest.raises(ValueError), atomic_path(target) as tmp:
        with open(tmp, "wb") as f:
            f.write(b"partial")
        raise ValueError("writer bug")
    assert target.read_bytes() == b"old"
    _only_file(tmp_path, "out.bin")


# ----------------------------------------------------------- user errors
def _unwritable_paths(tmp_path):
    (tmp_path / "file").write_text("x")
    (tmp_path / "dir").mkdir()
    return {
        "missing directory": tmp_path / "missing" / "image.{ext}",
        "parent is a file": tmp_path / "file" / "image.{ext}",
        "path is a directory": tmp_path / "dir",
    }


@pytest.mark.parametrize("kind", ["missing directory", "parent is a file",
                                  "path is a directory"])
@pytest.mark.parametrize("ext", ["exr", "png"])
def test_unwritable_path_raises_one_line_mcrt_error(tmp_path, kind, ext):
    path = str(_unwritable_paths(tmp_path)[kind]).format(ext=ext)
    with pytest.raises(McrtError) as info:
        if ext == "exr":
            write_exr(path, {"rgb": np.zeros((2, 2, 3))})
        else:
            write_png(path, np.zeros((2, 2, 3)))
    message = str(info.value)
    assert isinstance(info.value, ImageIOError)
    assert "\n" not in message and path in message and message.startswith("cannot write")


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0,
                    reason="root ignores directory permissions")
def test_read_only_directory_raises_mcrt_error(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(ImageIOError, match="permission denied"):
            write_exr(ro / "x.exr", {"rgb": np.zeros((2, 2, 3))})
    finally:
        ro.chmod(0o700)


def test_read_errors_are_mcrt_errors(tmp_path):
    with pytest.raises(ImageIOError, match="no such file"):
        read_exr(tmp_path / "absent.exr")
    junk = tmp_path / "junk.exr"
    junk.write_bytes(b"not an exr")
    with pytest.raises(ImageIOError, match="not a readable OpenEXR file") as info:
        read_exr(junk)
    assert "\n" not in str(info.value)


# ---------------------------------------------------------------------- PNG
def _srgb_reference(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 written out independently of colour-science."""
    x = np.clip(x, 0.0, 1.0)
    v = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.floor(v * 255 + 0.5).astype(np.uint8)


@pytest.mark.parametrize("linear, code", [
    (0.0, 0),
    (0.5, 188),
    (1.0, 255),
    (2.0, 255),          # clipped before encoding
    (1e6, 255),
    (-0.5, 0),           # negative clipped to 0
    (0.001, 3),          # linear segment: 12.92 * 0.001 * 255 = 3.29
    (0.0031308, 10),     # the threshold: 0.04045 * 255 = 10.31
    (0.0031309, 10),
    (0.0045, 14),        # power segment just above the threshold: 0.0557 * 255 = 14.2
    (0.18, 118),         # photographic middle grey
])
def test_encode_srgb_known_values(linear, code):
    out = encode_srgb(np.full((1, 1, 3), linear))
    assert out.dtype == np.uint8 and out.shape == (1, 1, 3)
    assert out.tolist() == [[[code] * 3]]


def test_encode_srgb_matches_the_standard_curve():
    x = np.concatenate([np.linspace(0.0, 0.01, 2001), np.linspace(0.0, 1.2, 4001)])
    out = encode_srgb(np.repeat(x[None, :, None], 3, axis=2))[0, :, 0]
    ref = _srgb_reference(x)
    assert np.abs(out.astype(int) - ref).max() <= 1     # rounding ties only
    assert np.mean(out == ref) > 0.999
    assert np.all(np.diff(out[2001:].astype(int)) >= 0)  # monotone


def test_srgb_transfer_is_bit_identical_to_colour_science():
    """The numpy transfer function replaced colour.cctf_encoding (slow to import):
    same float64 values, hence the same PNG bytes as before."""
    colour = pytest.importorskip("colour")
    rng = np.random.default_rng(7)
    x = np.concatenate([
        np.linspace(0.0, 1.0, 100_001),
        rng.random(100_000),
        rng.random(10_000) * 0.01,                        # around the linear segment
        np.nextafter(SRGB_LINEAR_LIMIT, [0.0, 1.0]), [SRGB_LINEAR_LIMIT, 0.0, 1.0],
        (np.arange(256) / 255.0) ** 2.4,                  # near the 8-bit code boundaries
    ])
    ours = srgb_transfer(x)
    theirs = np.asarray(colour.cctf_encoding(x, function="sRGB"), dtype=np.float64)
    assert ours.dtype == np.float64
    np.testing.assert_array_equal(ours, theirs)
    # ... and so the 8-bit codes of encode_srgb agree as well.
    rgb = np.repeat(np.clip(x, 0, 1)[None, :, None], 3, axis=2)
    expected = np.floor(np.clip(theirs, 0, 1) * 255 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(encode_srgb(rgb)[0, :, 0], expected)


def test_png_path_does_not_import_colour_science():
    code = ("import sys\n"
            "import numpy as np\n"
            "from mcrt.io import encode_srgb\n"
            "encode_srgb(np.full((2, 2, 3), 0.5))\n"
            "assert 'colour' not in sys.modules, 'colour-science imported'\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_encode_srgb_exposure_and_channels():
    assert encode_srgb(np.full((1, 1, 3), 0.25), exposure=1.0)[0, 0, 0] == 188
    assert encode_srgb(np.full((1, 1, 3), 2.0), exposure=-2.0)[0, 0, 0] == 188
    rgb = np.array([[[0.5, 2.0, -1.0]]])
    assert encode_srgb(rgb).tolist() == [[[188, 255, 0]]]           # per-channel clip
    grey = encode_srgb(np.full((2, 3), 0.5))
    assert grey.shape == (2, 3, 3) and np.all(grey == 188)
    rgba = encode_srgb(np.array([[[0.5, 0.5, 0.5, 0.0]]]))
    assert rgba.tolist() == [[[188, 188, 188]]]                     # alpha ignored
    with pytest.raises(ValueError):
        encode_srgb(np.zeros((2, 2, 2)))
    with pytest.raises(ValueError):
        encode_srgb(np.zeros((1, 1, 3)), exposure=float("nan"))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_encode_srgb_nonfinite_pixels_are_magenta(bad):
    rgb = np.full((1, 3, 3), 0.5)
    rgb[0, 1, 2] = bad                     # one bad channel marks the whole pixel
    out = encode_srgb(rgb, exposure=3.0)
    assert tuple(out[0, 1]) == NONFINITE_COLOUR == (255, 0, 255)
    assert out[0, 0].tolist() == out[0, 2].tolist() == [255, 255, 255]  # 0.5 * 8 clipped


def test_write_png_reads_back_with_pillow(tmp_path):
    rng = np.random.default_rng(4)
    rgb = rng.random((9, 13, 3)) * 1.5
    rgb[3, 4, 0] = np.nan
    path = tmp_path / "out.png"
    write_png(path, rgb, exposure=-0.5)
    with Image.open(path) as im:
        assert im.format == "PNG" and im.mode == "RGB" and im.size == (13, 9)
        pixels = np.asarray(im)
    np.testing.assert_array_equal(pixels, encode_srgb(rgb, exposure=-0.5))
    assert tuple(pixels[3, 4]) == NONFINITE_COLOUR
    _only_file(tmp_path, "out.png")


def test_contact_sheet(tmp_path):
    a = np.empty((10, 20, 3))
    a[:] = [0.5, 0.0, 1.0]   # (188, 0, 255): a colour the grey labels cannot produce
    b = np.zeros((6, 8, 3))
    b[0, 0] = 1.0
    images = [("purple", a), ("black", b), ("a much longer title than the image", a)]
    sheet = contact_sheet(images, columns=2, zoom=3, title="demo")
    assert sheet.mode == "RGB"
    pixels = np.asarray(sheet)
    # Nearest-neighbour zoom: a 3x3 block of pure white from b's corner pixel,
    # next to b's black pixels.
    white = np.argwhere(np.all(pixels == 255, axis=2))
    assert len(white) >= 9
    tile = np.all(pixels == [188, 0, 255], axis=2)
    assert tile.sum() == 2 * 10 * 20 * 9      # both `a` tiles, every pixel, zoomed 3x

    path = tmp_path / "sheet.png"
    write_contact_sheet(path, images, columns=2, zoom=3, title="demo")
    with Image.open(path) as im:
        assert im.size == sheet.size
        np.testing.assert_array_equal(np.asarray(im), pixels)
    two_line = contact_sheet([("first line\nsecond line", a)])
    assert two_line.height > contact_sheet([("first line", a)]).height
    one_row = contact_sheet(images, columns=3)
    assert one_row.width > one_row.height
    with pytest.raises(ValueError):
        contact_sheet([])
    with pytest.raises(McrtError):
        write_contact_sheet(tmp_path / "missing" / "s.png", images)


def test_threshold_encoding_equals_the_transfer_function():
    """encode_srgb counts thresholds instead of evaluating the transfer function per
    pixel: the codes must be the same for every value, at and next to every
    threshold, and for 2e6 random float32 values (what films hold)."""
    from mcrt.io.png import _code, code_thresholds, encode_srgb

    t = code_thresholds()
    assert np.all(np.diff(t) > 0) and len(t) == 255
    rng = np.random.default_rng(7)
    x = np.concatenate([t, np.nextafter(t, 0.0), np.nextafter(t, 2.0), [0.0, 1.0],
                        rng.random(2_000_000).astype(np.float32),
                        (rng.random(200_000) * 0.004).astype(np.float32)])
    image = np.repeat(x[None, :, None], 3, axis=2)
    np.testing.assert_array_equal(encode_srgb(image)[0, :, 0], _code(np.clip(x, 0.0, 1.0)))


def test_float32_fast_path_gives_the_float64_codes():
    """float32 images at exposure 0 are encoded by a table on their top 16 bits;
    every float32 next to each of the 255 code thresholds, the specials and
    random values must get exactly the code of the float64 path."""
    from mcrt.io.png import code_thresholds

    t = code_thresholds().astype(np.float32)
    near = np.concatenate([t, np.nextafter(t, np.float32(0)), np.nextafter(t, np.float32(2)),
                           np.nextafter(np.nextafter(t, np.float32(2)), np.float32(2))])
    special = np.float32([0.0, -0.0, 1.0, 2.0, -1.0, np.nan, np.inf, -np.inf, 1e-38, 1e-45,
                          SRGB_LINEAR_LIMIT, np.nextafter(np.float32(1), np.float32(0))])
    rng = np.random.default_rng(3)
    values = np.concatenate([near, special, rng.random(30_000, np.float32),
                             rng.random(30_000, np.float32) ** 8]).astype(np.float32)
    values = values[: len(values) // 3 * 3].reshape(1, -1, 3)
    np.testing.assert_array_equal(encode_srgb(values), encode_srgb(values.astype(np.float64)))


def test_png_writer_is_read_back_by_pillow(tmp_path):
    """Our own PNG writer (no Pillow on the render path): Pillow decodes exactly
    the encoded bytes, for sizes that span several row chunks and IDAT pieces."""
    from mcrt.io.png import ROWS_PER_CHUNK

    rng = np.random.default_rng(5)
    for height, width in [(1, 1), (ROWS_PER_CHUNK + 3, 5), (2, 300)]:
        rgb = rng.random((height, width, 3)).astype(np.float32)
        rgb[0, 0] = np.nan
        path = tmp_path / f"{height}x{width}.png"
        write_png(path, rgb)
        with Image.open(path) as image:
            assert image.mode == "RGB" and image.size == (width, height)
            np.testing.assert_array_equal(np.asarray(image), encode_srgb(rgb))


def test_finite_values_beyond_float32_are_said_once_per_layer(tmp_path, caplog):
    """A float64 variance of huge radiance passes float32's 3.4e38: the file holds
    Inf there (read back with OpenEXR), said in one warning per layer with the
    count of such finite values, not as numpy's bare RuntimeWarning; Inf and NaN
    given as such are not counted."""
    import logging
    import warnings

    variance = np.array([[1e39, 2.0], [np.inf, np.nan]])
    rgb = np.ones((2, 2, 3))
    rgb[0, 0] = -1e300
    with warnings.catch_warnings(), caplog.at_level(logging.WARNING, logger="mcrt.io"):
        warnings.simplefilter("error")
        write_exr(tmp_path / "v.exr", {"rgb": rgb, "variance": variance},
                  channels={"Y": np.full((2, 2), 1.0)})
    messages = [r.getMessage() for r in caplog.records]
    assert messages == ["EXR layer rgb: 3 finite values beyond float32's range (3.4e38) are "
                        "stored as Inf",
                        "EXR layer variance: 1 finite values beyond float32's range (3.4e38) "
                        "are stored as Inf"], messages
    back = OpenEXR.File(str(tmp_path / "v.exr")).channels()
    assert back["variance.Y"].pixels[0, 0] == np.inf and back["variance.Y"].pixels[0, 1] == 2.0
    assert (back["RGB"].pixels[0, 0] == -np.inf).all()
