"""The distribution's headless Chromium for the tests that look at a page (no browser download at run time)."""
import contextlib
import os
import shutil
import tempfile

import pytest


@contextlib.contextmanager
def chromium():
    """A Selenium driver of the distribution's headless Chromium, with the browser's console log, quit after; skips
    the test (one line: how to install it) where there is none. Its profile and the temporary files it leaves behind
    are in a folder of their own, removed after (short: its socket's path has at most 107 characters)."""
    chromium, driver = shutil.which("chromium") or shutil.which("chromium-browser"), shutil.which("chromedriver")
    try:
        import selenium  # noqa: F401
    except ImportError:
        chromium = None
    if not (chromium and driver):
        pytest.skip("no headless Chromium: apt-get install chromium chromium-driver (Debian) and pip install selenium")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = chromium
    for a in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
              "--disable-background-networking", "--disable-component-update", "--disable-sync",
              "--disable-dev-shm-usage"):
        opts.add_argument(a)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    folder = tempfile.mkdtemp(prefix="vpr-chromium-")
    try:
        opts.add_argument(f"--user-data-dir={os.path.join(folder, 'profile')}")
        browser = webdriver.Chrome(service=Service(driver, env={**os.environ, "TMPDIR": folder}), options=opts)
        try:
            yield browser
        finally:
            browser.quit()
    finally:
        shutil.rmtree(folder, ignore_errors=True)
