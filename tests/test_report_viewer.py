"""The study report's image viewer: its data, the EXR files, and the page in headless Chromium.

One tiny study (checkerboard at 64x48, two samplers, 4 and 16 spp, two seeds; ~5 s) is
rendered once for the module. The browser tests drive Debian's ``chromium`` through
``chromium-driver`` with Selenium (both installed by scripts/setup.sh); they skip, saying
why, only when no Chromium can be started, and fail instead when ``MCRT_REQUIRE_BROWSER``
or ``CI`` is set (scripts/test.sh sets it once setup found the browser).
"""

from __future__ import annotations

import os
import re
import shutil

import numpy as np
import pytest
from conftest import CHECKERBOARD, study_toml

from mcrt.analysis.metrics import luminance
from mcrt.analysis.viewer import decode_array, encode_array, hardest_regions, scene_data
from mcrt.io import read_exr

SCENE = "checkerboard"


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    from mcrt.analysis.report import write_report
    from mcrt.analysis.study import load_config, run_study

    tmp = tmp_path_factory.mktemp("viewer")
    config = tmp / "study.toml"
    config.write_text(study_toml(CHECKERBOARD, name="tiny"))
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("MCRT_CACHE_DIR", str(tmp / "cache"))
        result = run_study(load_config(config))
    files = write_report(result, tmp / "report")
    return result, files


# --------------------------------------------------------------------------- data and files


def test_arrays_round_trip_bit_for_bit():
    rng = np.random.default_rng(1)
    a = rng.standard_normal((5, 7, 3)).astype(np.float32)
    a[1, 2, 0], a[3, 3, 2], a[0, 0, 1] = np.nan, np.inf, -0.0
    back = decode_array(encode_array(a), a.shape)
    assert back.tobytes() == a.tobytes()


def test_the_hardest_region_is_where_the_error_is():
    error = np.zeros((60, 80))
    error[30:40, 50:60] = 1.0                   # one bad block ...
    error[5:8, 5:8] = 0.5                       # ... and a milder one
    crops = hardest_regions([error, error * 0.5], count=2)
    (x, y, size), (x2, y2, _) = crops
    assert size == 12 and x <= 50 and x + size >= 60 and y <= 30 and y + size >= 40
    assert x2 <= 5 and x2 + size >= 8 and y2 <= 5 and y2 + size >= 8   # not overlapping


def test_every_cell_is_written_as_exr_and_linked(study):
    result, files = study
    out = files["report"].parent
    html = files["report"].read_text()
    assert len(result.renders) == 4
    for (scene, label, spp), renders in result.renders.items():
        mean = out / "exr" / scene / f"{label}_{spp}spp_mean.exr"
        first = out / "exr" / scene / f"{label}_{spp}spp_seed0.exr"
        layers, meta = read_exr(mean)
        assert np.array_equal(layers["rgb"], renders.mean)
        assert np.array_equal(layers["variance"], renders.variance)
        assert meta["sampler"] == label and meta["spp"] == spp
        layers, meta = read_exr(first)
        assert np.array_equal(layers["rgb"], renders.first) and meta["seed"] == 0
        for path in (mean, first):  # linked from the viewer's data
            assert f'"{path.relative_to(out).as_posix()}"' in html
    ref, _ = read_exr(out / "exr" / SCENE / "reference.exr")
    assert np.array_equal(ref["rgb"], result.reference_images[SCENE].astype(np.float32))
    # The mean over seeds really is the mean of the seeds' renders.
    cell = result.renders[(SCENE, "independent", 4)]
    assert not np.array_equal(cell.mean, cell.first)


def test_the_report_is_one_offline_file_with_a_viewer(study):
    _, files = study
    html = files["report"].read_text()
    assert "<link" not in html and not re.search(r"""src=['"]?(https?:)?//""", html)
    assert "http://" not in html.replace("http://www.w3.org", "")
    assert html.count("class='mcrt-viewer'") == 1
    assert "image-rendering:pixelated" in html and "DecompressionStream" in html
    assert "<nav class='toc'>" in html and "href='#viewer-0'" in html
    assert html.count("<table class=\"sortable") >= 3
    assert "unresolved" in html and "labels give the sample count" in html


def test_viewer_data_hold_the_true_values(study):
    result, files = study
    out = files["report"].parent
    data = scene_data(result, SCENE, {})
    h, w = data["height"], data["width"]
    assert (w, h) == (64, 48) and data["samplers"] == ["jittered", "independent"]
    cell = data["cells"]["jittered/16"]
    renders = result.renders[(SCENE, "jittered", 16)]
    assert np.array_equal(decode_array(cell["first"], (h, w, 3)), renders.first)
    assert np.array_equal(decode_array(cell["variance"], (h, w)), renders.variance)
    flip = decode_array(cell["flip"], (h, w))
    assert 0 <= flip.min() and flip.max() <= 1 and abs(flip.mean() - cell["flip_mean"]) < 1e-4
    # More samples, less FLIP error.
    assert data["cells"]["independent/16"]["flip_mean"] < data["cells"]["independent/4"]["flip_mean"]
    assert len(data["crops"]) == 3 and all(c[2] == 9 for c in data["crops"])
    assert out.is_dir()


# --------------------------------------------------------------------------- the browser


def _browser_paths() -> tuple[str | None, str | None]:
    browser = next((shutil.which(b) for b in ("chromium", "chromium-browser", "google-chrome",
                                              "google-chrome-stable") if shutil.which(b)), None)
    drivers = ["chromedriver"]
    if os.environ.get("CHROMEWEBDRIVER"):
        drivers.insert(0, os.path.join(os.environ["CHROMEWEBDRIVER"], "chromedriver"))
    driver = next((shutil.which(d) for d in drivers if shutil.which(d)), None)
    return browser, driver


def _no_browser(reason: str):
    if os.environ.get("MCRT_REQUIRE_BROWSER") or os.environ.get("CI"):
        pytest.fail(f"the browser test must run here but cannot: {reason}")
    pytest.skip(f"headless Chromium cannot run: {reason} (scripts/setup.sh installs "
                "Debian's chromium and chromium-driver)")


@pytest.fixture(scope="module")
def browser():
    try:
        from selenium import webdriver
        from selenium.common.exceptions import WebDriverException
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service
    except ImportError as error:
        _no_browser(f"selenium is not installed ({error})")
    binary, driver_path = _browser_paths()
    if binary is None or driver_path is None:
        _no_browser("no chromium / chromedriver on PATH")
    options = Options()
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                "--window-size=1300,1000", "--force-device-scale-factor=1"):
        options.add_argument(arg)
    options.binary_location = binary
    try:
        driver = webdriver.Chrome(options=options, service=Service(driver_path))
    except WebDriverException as error:
        _no_browser(f"{binary} with {driver_path} did not start: {error.msg}")
    yield driver
    driver.quit()


def _open(browser, files):
    from selenium.webdriver.support.ui import WebDriverWait

    browser.get(files["report"].resolve().as_uri())
    viewer = browser.find_element("css selector", ".mcrt-viewer")
    WebDriverWait(browser, 20).until(lambda _: viewer.get_attribute("data-ready") == "1")
    browser.execute_script("arguments[0].scrollIntoView(); arguments[0].focus();", viewer)
    return viewer


def _keys(browser, keys: str) -> None:
    from selenium.webdriver.common.action_chains import ActionChains

    ActionChains(browser).send_keys(keys).perform()


def _shown(viewer):
    """The canvas of the one visible panel in the "one image" layout."""
    return viewer.find_element("css selector", "[data-panel='selected'] canvas")


def test_keys_switch_the_image(study, browser):
    _, files = study
    viewer = _open(browser, files)
    _keys(browser, "g")  # one image at a time
    canvas = _shown(viewer)
    pixels = "return arguments[0].toDataURL();"
    assert canvas.get_attribute("data-shows") == "jittered/16/first/image"
    before = browser.execute_script(pixels, canvas)
    _keys(browser, "2")
    assert viewer.get_attribute("data-sampler") == "independent"
    assert canvas.get_attribute("data-shows") == "independent/16/first/image"
    assert browser.execute_script(pixels, canvas) != before
    _keys(browser, "r")
    assert canvas.get_attribute("data-shows") == "reference"
    _keys(browser, "r")
    _keys(browser, "\ue012")  # left arrow: fewer samples
    assert canvas.get_attribute("data-shows") == "independent/4/first/image"
    for key, view in (("s", "signed"), ("a", "abs"), ("e", "rel"), ("f", "flip"),
                      ("v", "variance"), ("m", "variance")):
        _keys(browser, key)
        assert viewer.get_attribute("data-view") == view
    assert canvas.get_attribute("data-shows") == "independent/4/mean/variance"
    bar = viewer.find_element("css selector", ".vw-colourbar")
    assert bar.is_displayed() and "variance" in bar.text
    _keys(browser, "im\ue014g")  # back: image, first seed, more samples, grid


def test_zoom_enlarges_native_pixels_without_resampling(study, browser):
    result, files = study
    viewer = _open(browser, files)
    canvas = viewer.find_element("css selector", "[data-panel='0'] canvas")
    size = "var r = arguments[0].getBoundingClientRect(); return [r.width, r.height];"
    style = "return getComputedStyle(arguments[0]).imageRendering;"
    assert browser.execute_script(style, canvas) == "pixelated"
    w, h = result.reference_images[SCENE].shape[1], result.reference_images[SCENE].shape[0]
    assert (int(canvas.get_attribute("width")), int(canvas.get_attribute("height"))) == (w, h)
    zoom = int(viewer.get_attribute("data-zoom"))
    assert browser.execute_script(size, canvas) == [w * zoom, h * zoom]
    _keys(browser, "+")
    bigger = int(viewer.get_attribute("data-zoom"))  # +1 up to 4x, then doubling
    assert bigger == (zoom + 1 if zoom < 4 else 2 * zoom)
    assert browser.execute_script(size, canvas) == [w * bigger, h * bigger]
    assert int(canvas.get_attribute("width")) == w  # still the native image
    _keys(browser, "0")
    assert browser.execute_script(size, canvas) == [w * zoom, h * zoom]


def test_the_readout_shows_a_pixels_true_values(study, browser, tmp_path):
    from selenium.webdriver.common.action_chains import ActionChains

    result, files = study
    viewer = _open(browser, files)
    _keys(browser, "0")
    canvas = viewer.find_element("css selector", "[data-panel='1'] canvas")  # independent
    zoom = int(viewer.get_attribute("data-zoom"))
    rect = browser.execute_script(
        "var r = arguments[0].getBoundingClientRect(); return [r.width, r.height];", canvas)
    x, y = 37, 21
    ActionChains(browser).move_to_element_with_offset(
        canvas, int((x + 0.5) * zoom - rect[0] / 2), int((y + 0.5) * zoom - rect[1] / 2)).perform()
    readout = viewer.find_element("css selector", ".vw-readout")
    assert (readout.get_attribute("data-x"), readout.get_attribute("data-y")) == (str(x), str(y))

    def row(cls):
        return [float(s.get_attribute("data-value"))
                for s in readout.find_elements("css selector", f".{cls} .vw-num")]

    cell = result.renders[(SCENE, "independent", 16)]
    value, ref = row("vw-value-row"), row("vw-ref-row")
    assert np.array_equal(np.float32(value[:3]), cell.first[y, x])
    assert value[3] == pytest.approx(luminance(cell.first[y, x]), rel=1e-6)
    expected_ref = result.reference_images[SCENE][y, x].astype(np.float32)
    assert np.array_equal(np.float32(ref[:3]), expected_ref)
    assert row("vw-sd-row")[0] == pytest.approx(float(np.sqrt(cell.variance[y, x])), rel=1e-6)
    assert f"pixel ({x}, {y})" in readout.text
    shot = tmp_path / "viewer.png"
    viewer.screenshot(str(shot))
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
