"""A headless Chromium (Debian's `chromium`) driven by Selenium through Debian's
`chromium-driver`, the maintained WebDriver client.

The driver is named by its path (``Service(executable_path=...)``), so Selenium Manager never
looks for (or downloads) a driver or a browser: both come from the same Debian release and
match. Tests pass values to the page as ``execute_script`` arguments and wait with
``WebDriverWait`` on Python predicates; no JavaScript is assembled from strings.
"""

from __future__ import annotations

import base64
import io
import os
import shutil

import numpy as np

#: Debian's packages install these (`make chromium`: scripts/ensure_optional.py).
CHROMIUM_NAMES = ("chromium", "chromium-browser")
CHROMEDRIVER_NAMES = ("chromedriver",)
#: The window the tests (and the README's screenshot) see, CSS pixels.
WINDOW = (1000, 900)
#: The flags a root-run headless Chromium needs here, and no network of its own.
FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--force-device-scale-factor=1",
    "--hide-scrollbars",
)


def _found(names: tuple[str, ...]) -> str | None:
    return next((p for p in map(shutil.which, names) if p), None)


def chromium_path() -> str | None:
    return _found(CHROMIUM_NAMES)


def chromedriver_path() -> str | None:
    return _found(CHROMEDRIVER_NAMES)


def unavailable_reason() -> str | None:
    """Why no headless browser test can run here, or None when it can."""
    absent = [name for name, path in (("chromium", chromium_path()), ("chromedriver", chromedriver_path())) if not path]
    try:
        import selenium  # noqa: F401 - the dev extra's client
    except ImportError:
        absent.append("the selenium package (the dev extra)")
    if absent:
        return (
            f"headless Chromium not available: {', '.join(absent)} not found (`make chromium`, part of `make test`, "
            "installs Debian's chromium and chromium-driver as root with apt-get)"
        )
    return None


def start_browser(profile_dir: str):
    """A Selenium WebDriver on a new headless Chromium of :data:`WINDOW`, its profile in ``profile_dir``."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = chromium_path()
    for flag in (*FLAGS, f"--user-data-dir={profile_dir}", f"--window-size={WINDOW[0]},{WINDOW[1]}"):
        options.add_argument(flag)
    service = Service(executable_path=chromedriver_path(), log_output=os.devnull)
    driver = webdriver.Chrome(service=service, options=options)
    driver.set_script_timeout(60)
    # The viewport, not the window, is what a screenshot holds: make it exactly WINDOW.
    driver.execute_cdp_cmd(
        "Emulation.setDeviceMetricsOverride",
        {"width": WINDOW[0], "height": WINDOW[1], "deviceScaleFactor": 1, "mobile": False},
    )
    return driver


def data_url_pixels(url: str) -> np.ndarray:
    """The pixels (H, W, 3) uint8 of a ``data:image/png;base64,...`` URL."""
    from PIL import Image

    prefix = "data:image/png;base64,"
    assert url.startswith(prefix), url[:40]
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url[len(prefix) :]))).convert("RGB"))
