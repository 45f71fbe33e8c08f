"""The app in a real browser: Debian's Chromium, headless, driven by Selenium.

Uploads an RGB photo (the example object on a gradient, no alpha), waits for the automatic mask to
appear in the mask field, turns the azimuth slider (the E_L preview must change), clicks Relight and
waits for the full-size relit photo; saves a screenshot (`GAFFER_TEST_ARTIFACTS`, else the test's tmp
folder). Skips, saying why, where Chromium or its driver is missing; `nox -s tests` installs both.
"""

import os
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.slow

WAIT_S = 120.0
"""Longest wait for one page change (first load compiles nothing, but CI machines are busy)."""


def _binaries() -> tuple[str, str]:
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver")
    if browser is None or driver is None:
        pytest.skip(
            "Chromium or chromedriver is not installed: apt-get install chromium chromium-driver "
            "(nox -s tests does this when run as root on Debian)"
        )
    return browser, driver


@pytest.fixture
def browser(tmp_path: Path) -> Any:
    pytest.importorskip(
        "selenium", reason='the browser test needs selenium: pip install "gaffer-diffusion[all]"'
    )
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    chromium, chromedriver = _binaries()
    os.environ.setdefault("SE_AVOID_STATS", "true")  # Selenium Manager stays offline and quiet
    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for arg in (
        "--headless=new",
        "--no-sandbox",  # CI runs as root
        "--disable-dev-shm-usage",
        "--disable-gpu",
        "--window-size=1280,1650",
        "--hide-scrollbars",
        f"--user-data-dir={tmp_path / 'chromium-profile'}",
    ):
        options.add_argument(arg)
    driver = webdriver.Chrome(service=Service(executable_path=chromedriver), options=options)
    yield driver
    driver.quit()


def _artifact_dir(tmp_path: Path) -> Path:
    out = Path(os.environ.get("GAFFER_TEST_ARTIFACTS", tmp_path))
    out.mkdir(parents=True, exist_ok=True)
    return out


def _rgb_photo(out: Path) -> Path:
    """The shipped example object, enlarged, on an opaque gradient: a 360x240 photo without alpha."""
    from gaffer_diffusion.pretrained import example_dataset_path

    rgba = sorted((example_dataset_path() / "objects").iterdir())[0] / "lit" / "000_000.png"
    obj = Image.open(rgba).convert("RGBA").resize((200, 200), Image.Resampling.LANCZOS)
    grad = np.zeros((240, 360, 4), np.uint8)
    grad[..., 0] = np.linspace(60, 150, 360)[None, :].astype(np.uint8)
    grad[..., 1] = np.linspace(90, 130, 240)[:, None].astype(np.uint8)
    grad[..., 2], grad[..., 3] = 150, 255
    canvas = Image.fromarray(grad)
    canvas.alpha_composite(obj, (80, 20))
    canvas.convert("RGB").save(out, quality=95)
    return out


def test_relight_in_a_browser(app_server: Any, browser: Any, tmp_path: Path) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    photo = _rgb_photo(tmp_path / "photo.jpg")
    wait = WebDriverWait(browser, WAIT_S)
    t0 = time.perf_counter()
    browser.get(app_server.url)

    def src(css: str) -> Any:
        def check(driver: Any) -> str | bool:
            found = driver.find_elements(By.CSS_SELECTOR, css)
            return bool(found) and (found[0].get_attribute("src") or False)

        return check

    first_ldr = wait.until(src("#ldr img"))  # the page's load event drew the previews
    upload = wait.until(
        ec.presence_of_element_located((By.CSS_SELECTOR, "#photo input[type=file]"))
    )
    upload.send_keys(str(photo))
    wait.until(src("#photo img"))
    wait.until(src("#mask img"))  # no alpha: GrabCut's mask is shown, replaceable by an upload
    slider = wait.until(ec.element_to_be_clickable((By.CSS_SELECTOR, "#azimuth input[type=range]")))
    slider.send_keys(*([Keys.ARROW_RIGHT] * 45))
    wait.until(lambda d: (src("#ldr img")(d) or first_ldr) != first_ldr)
    browser.find_element(By.CSS_SELECTOR, "#relight").click()
    relit = wait.until(src("#relit img"))
    status = wait.until(
        ec.text_to_be_present_in_element((By.CSS_SELECTOR, "#status"), "Relit with")
    )
    seconds = time.perf_counter() - t0
    assert status and relit
    text = browser.find_element(By.CSS_SELECTOR, "#status").text
    assert "360x240" in text and "GrabCut" in text, text
    assert int(slider.get_attribute("value") or -1) == 45
    shot = _artifact_dir(tmp_path) / "app_browser.png"
    browser.save_screenshot(str(shot))
    assert shot.stat().st_size > 10_000
    print(f"browser test: page to relit image in {seconds:.1f} s; screenshot {shot}")


def _click_at(browser: Any, img: Any, x: float, y: float) -> None:
    """Click the pixel (x, y) of a shown image, as a user sees it (scaled to fit, centred)."""
    from selenium.webdriver.common.action_chains import ActionChains

    w, h, nw, nh = browser.execute_script(
        "const r = arguments[0].getBoundingClientRect();"
        "return [r.width, r.height, arguments[0].naturalWidth, arguments[0].naturalHeight];",
        img,
    )
    s = min(w / nw, h / nh)
    cx = (w - nw * s) / 2 + (x + 0.5) * s - w / 2  # offsets from the element's centre
    cy = (h - nh * s) / 2 + (y + 0.5) * s - h / 2
    ActionChains(browser).move_to_element_with_offset(img, round(cx), round(cy)).click().perform()


def test_insert_in_a_browser(app_server: Any, browser: Any, tmp_path: Path) -> None:
    """The insert tab: upload an object and a background, click where it stands and where the key
    light is, set the height, insert; the fields follow the clicks (within the one or two image
    pixels a screen pixel covers when the preview is shown smaller)."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support import expected_conditions as ec
    from selenium.webdriver.support.ui import WebDriverWait

    from gaffer_diffusion.app.inserting import key_light_from_click
    from gaffer_diffusion.pretrained import example_dataset_path

    obj = example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"
    grad = np.zeros((480, 640, 3), np.uint8)
    grad[..., 0] = np.linspace(60, 150, 640)[None, :].astype(np.uint8)
    grad[..., 1] = np.linspace(150, 90, 480)[:, None].astype(np.uint8)
    grad[..., 2] = 120
    Image.fromarray(grad).save(tmp_path / "background.png")
    wait = WebDriverWait(browser, WAIT_S)
    browser.get(app_server.url)
    tab = "//button[@role='tab'][contains(., 'Insert into a photo')]"
    wait.until(ec.element_to_be_clickable((By.XPATH, tab))).click()
    upload = (By.CSS_SELECTOR, "#insert_object input[type=file]")
    wait.until(ec.presence_of_element_located(upload)).send_keys(str(obj))
    browser.find_element(By.CSS_SELECTOR, "#insert_background input[type=file]").send_keys(
        str(tmp_path / "background.png")
    )
    place = wait.until(ec.presence_of_element_located((By.CSS_SELECTOR, "#insert_place img")))
    wait.until(lambda d: d.execute_script("return arguments[0].naturalWidth", place) == 640)

    def value(css: str) -> float:
        return float(browser.find_element(By.CSS_SELECTOR, css).get_attribute("value") or "nan")

    _click_at(browser, place, 400, 420)
    wait.until(lambda d: abs(value("#insert_x input") - 400) <= 2)
    assert abs(value("#insert_y input") - 420) <= 2
    key = wait.until(ec.presence_of_element_located((By.CSS_SELECTOR, "#insert_key_view img")))
    wait.until(lambda d: d.execute_script("return arguments[0].naturalWidth", key) == 512)
    _click_at(browser, key, 150, 60)
    want_az, want_el = key_light_from_click((150, 60))
    azimuth = "#insert_key_azimuth input[type=number]"
    wait.until(lambda d: abs(value(azimuth) - want_az) < 3)
    assert abs(value("#insert_key_elevation input[type=number]") - want_el) < 3
    height = browser.find_element(By.CSS_SELECTOR, "#insert_height input[type=number]")
    height.clear()
    height.send_keys("200\n")
    browser.find_element(By.CSS_SELECTOR, "#insert").click()
    status = (By.CSS_SELECTOR, "#insert_status")
    wait.until(ec.text_to_be_present_in_element(status, "Inserted with"))
    text = browser.find_element(*status).text
    assert "640x480" in text and "200 px tall" in text and "2d shadow" in text, text
    wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#insert_result img"))
    shot = _artifact_dir(tmp_path) / "app_insert_browser.png"
    browser.save_screenshot(str(shot))
    assert shot.stat().st_size > 10_000
