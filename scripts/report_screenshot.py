"""Screenshot of a study report's first image viewer in headless Chromium (docs/report_viewer.png).

    python scripts/report_screenshot.py out/compare/quick/report.html docs/report_viewer.png

Needs selenium and Debian's chromium + chromium-driver (scripts/setup.sh installs them).
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", type=Path, help="report.html of a study")
    parser.add_argument("png", type=Path, help="where to write the screenshot")
    parser.add_argument("--keys", default="", help="keys to press first, e.g. 'g2'")
    args = parser.parse_args(argv)

    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.support.ui import WebDriverWait

    options = Options()
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1400,1400",
                "--force-device-scale-factor=1"):
        options.add_argument(arg)
    binary = shutil.which("chromium") or shutil.which("google-chrome")
    if binary:
        options.binary_location = binary
    driver_path = shutil.which("chromedriver")
    driver = webdriver.Chrome(options=options,
                              service=Service(driver_path) if driver_path else None)
    try:
        driver.get(args.report.resolve().as_uri())
        viewer = driver.find_element("css selector", ".mcrt-viewer")
        WebDriverWait(driver, 60).until(lambda _: viewer.get_attribute("data-ready") == "1")
        driver.execute_script("arguments[0].scrollIntoView(); arguments[0].focus();", viewer)
        if args.keys:
            ActionChains(driver).send_keys(args.keys).perform()
        canvas = viewer.find_element("css selector", "[data-panel='1'] canvas")
        # images load lazily: wait until every panel's canvas has drawn its image
        panels = viewer.find_elements("css selector", "[data-panel] canvas")
        WebDriverWait(driver, 60).until(
            lambda _: all(c.get_attribute("data-drawn") for c in panels if c.is_displayed()))
        ActionChains(driver).move_to_element(canvas).perform()  # fill the readout
        args.png.parent.mkdir(parents=True, exist_ok=True)
        viewer.screenshot(str(args.png))
    finally:
        driver.quit()
    print(f"wrote {args.png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
