"""The live page in a real browser: the distribution's headless Chromium driven by Selenium.

Chromium and chromedriver come from the distribution (.ci/browser/install, run by
scripts/test when CI=true or with --socketcan). Without them the test is skipped with the reason,
except under CI=true, where it fails. ``FIELDGATE_SCREENSHOT=docs/observability-page.png``
saves the page as docs/observability.md shows it.
"""

from __future__ import annotations

import asyncio
import os
import shutil
import time
from pathlib import Path

import pytest
from httpkit import EXAMPLES, Running, load_gateway, start

from fieldgate.plugins.modbus.simulator import Fault

pytestmark = pytest.mark.browser

FAULT_COLOUR = "rgb(214, 69, 69)"  # --q-comm-fault in style.css
GOOD_COLOUR = "rgb(46, 157, 91)"  # --q-good


def _missing(why: str) -> None:
    if os.environ.get("CI") == "true":
        pytest.fail(f"{why} (CI=true: .ci/browser/install should have installed it)")
    pytest.skip(
        f"{why}: run .ci/browser/install (or scripts/test --socketcan) to test the page in Chromium"
    )


@pytest.fixture
def driver():
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        _missing("selenium is not installed")
    browser = (
        os.environ.get("FIELDGATE_CHROMIUM")
        or shutil.which("chromium")
        or shutil.which("chromium-browser")
    )
    chromedriver = os.environ.get("FIELDGATE_CHROMEDRIVER") or shutil.which("chromedriver")
    if not browser or not chromedriver:
        _missing("headless Chromium or chromedriver not found")
    options = Options()
    options.binary_location = browser
    for arg in (
        "--headless=new",
        "--no-sandbox",
        "--disable-dev-shm-usage",
        "--window-size=1400,1050",
    ):
        options.add_argument(arg)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    # explicit paths: Selenium Manager downloads nothing
    d = webdriver.Chrome(service=Service(chromedriver), options=options)
    try:
        yield d
    finally:
        d.quit()


def wait_js(driver, script: str, timeout: float) -> object:
    """Poll a JavaScript expression in the page until it is truthy; returns its value."""
    from selenium.common.exceptions import TimeoutException
    from selenium.webdriver.support.ui import WebDriverWait

    if not script.startswith("return "):
        script = "return " + script
    try:
        return WebDriverWait(driver, timeout, poll_frequency=0.05).until(
            lambda d: d.execute_script(script)
        )
    except TimeoutException:
        logs = driver.get_log("browser")
        raise AssertionError(f"{script}: not true after {timeout} s; browser log: {logs}") from None


def tile(point: str) -> str:
    return f"document.querySelector('.tile[data-point=\"{point}\"]')"


async def test_the_page_shows_modules_live_values_and_faults(driver, tmp_path):
    gw = load_gateway(tmp_path)
    running: Running = await start(gw)
    try:
        await asyncio.to_thread(check_page, driver, running, asyncio.get_running_loop())
    finally:
        await gw.stop()


def check_page(driver, running: Running, loop: asyncio.AbstractEventLoop) -> None:
    gw = running.gateway

    def loop_call(action) -> None:
        """Run ``action`` on the gateway's event loop (the simulator lives there), wait for it."""
        asyncio.run_coroutine_threadsafe(_call(action), loop).result(timeout=10)

    url = f"http://127.0.0.1:{running.port}/"
    driver.get(url)
    wait_js(driver, "document.querySelectorAll('#modules tbody tr[data-module]').length === 4", 10)
    wait_js(driver, "document.getElementById('live').textContent === 'live'", 10)

    # every module: in the table (online) and in the process-image grid with all its points
    rows = driver.execute_script(
        "return [...document.querySelectorAll('#modules tbody tr')].map(r => [r.dataset.module, r.dataset.health])"
    )
    assert rows == [[f"rs485/m{a}", "online"] for a in (1, 3, 4, 5)]
    boxes = driver.execute_script(
        "return [...document.querySelectorAll('.module')].map(m => m.dataset.module)"
    )
    assert boxes == ["rs485/m1", "rs485/m3", "rs485/m4", "rs485/m5"]
    tiles = driver.execute_script(
        "return [...document.querySelectorAll('.tile')].map(t => t.dataset.point)"
    )
    assert tiles == [c.id for c in gw.image]
    assert (
        driver.execute_script(f"return getComputedStyle({tile('rs485/m1/di0')}).backgroundColor")
        == GOOD_COLOUR
    )

    # a value changed in the simulator appears within 2 s
    simulator = gw.bench.simulator("rs485")
    before = gw.image.value("rs485/m1/di5")
    changed_at = time.monotonic()
    loop_call(lambda: simulator.set_input("rs485/m1/di5", not before))
    wait_js(
        driver, f"return {tile('rs485/m1/di5')}.dataset.value === '{str(not before).lower()}'", 2.0
    )
    assert time.monotonic() - changed_at <= 2.0
    # analog steps, each shown within 2 s (they draw the trend plot)
    for n, value in enumerate((4000, 9000, 16000, 12000, 22000, 30000, 26000)):
        loop_call(lambda v=value: simulator.set_input("rs485/m5/ai0", v))
        wait_js(driver, f"return {tile('rs485/m5/ai0')}.dataset.value === '{value}'", 2.0)
        if n < 6:
            time.sleep(0.4)  # spread the steps on the plot's time axis

    # a stopped module turns to its fault colour, in the grid and the table
    loop_call(lambda: simulator.inject(5, Fault("no_answer")))
    wait_js(driver, f"return {tile('rs485/m5/ai0')}.dataset.quality === 'comm-fault'", 15)
    # (after the tile's 0.25 s colour transition)
    fault = f"getComputedStyle({tile('rs485/m5/ai0')}).backgroundColor === '{FAULT_COLOUR}'"
    wait_js(driver, fault, 2.0)
    wait_js(
        driver,
        "return document.querySelector('tr[data-module=\"rs485/m5\"]').dataset.health === 'offline'",
        10,
    )
    wait_js(
        driver,
        "return document.querySelector('#events li[data-kind=\"module-offline\"]') !== null",
        10,
    )
    assert driver.execute_script(
        "return document.querySelector('.module[data-module=\"rs485/m5\"]').classList.contains('offline')"
    )

    # hovering a point explains it: quality, cause, source and where the front serves it
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    ActionChains(driver).move_to_element(
        driver.find_element(By.CSS_SELECTOR, '.tile[data-point="rs485/m5/ai0"]')
    ).perform()
    wait_js(driver, "return document.getElementById('tip').textContent.includes('TPDO2')", 5)
    tip = driver.find_element(By.ID, "tip").text
    assert "comm-fault" in tip and "module offline after" in tip and "input register 0 (FC4)" in tip

    severe = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
    assert severe == [], severe  # no console errors
    screenshot = os.environ.get("FIELDGATE_SCREENSHOT")
    if screenshot:
        Path(screenshot).parent.mkdir(parents=True, exist_ok=True)
        assert driver.save_screenshot(screenshot)


async def _call(action) -> None:
    action()


async def test_the_page_shows_what_a_back_found_on_its_line(driver, tmp_path):
    """examples/i7241d-style.yaml (modules: auto) on its scan file's simulated modules."""
    gw = load_gateway(tmp_path, "i7241d-style.yaml")
    running: Running = await start(gw)
    try:
        url = f"http://127.0.0.1:{running.port}/"
        await asyncio.to_thread(driver.get, url)
        script = "document.querySelector('#line-notes li[data-back=\"rs485\"]')?.textContent"
        text = await asyncio.to_thread(wait_js, driver, f"return {script}", 10)
        assert text == (
            "rs485: found at start (9600 bit/s, checksum off): I-7055 at 1, "
            "I-7017 at 2 (type 0x08 +/-10 V, hex), I-7024 at 3 (type 0x33 +/-10 V, hex)"
        )
        rows = await asyncio.to_thread(
            driver.execute_script,
            "return [...document.querySelectorAll('#modules tbody tr')].map(r => r.dataset.module)",
        )
        assert rows == ["rs485/m1", "rs485/m2", "rs485/m3"]
    finally:
        await gw.stop()


async def test_the_page_shows_a_start_scan_that_found_no_line(driver, tmp_path):
    """examples/i7241d-style.yaml without its serial port (docs/dcon.md, "modules: auto without
    its line"): the note says why and where the modules come from; the page has no error."""
    from fieldgate import Gateway

    gw = Gateway.load(
        EXAMPLES / "i7241d-style.yaml",
        overrides={
            "gateway.state_dir": str(tmp_path / "state"),
            "gateway.http.listen": "127.0.0.1:0",
            "fronts.0.interface": "virtual",
            "fronts.0.channel": f"fieldgate-http-noline-{os.getpid()}",
            "backs.0.port": str(tmp_path / "no-such-ttyUSB0"),
        },
    )
    running: Running = await start(gw)
    try:
        await asyncio.to_thread(driver.get, f"http://127.0.0.1:{running.port}/")
        script = "document.querySelector('#line-notes li[data-back=\"rs485\"]')?.textContent"
        text = await asyncio.to_thread(wait_js, driver, f"return {script}", 10)
        assert text.startswith("rs485: start scan failed: cannot open serial port ")
        assert (
            "modules from the scan file " in text
            and "I-7055 at 1, I-7017 at 2, I-7024 at 3" in text
        )
        severe = [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]
        assert severe == [], severe
    finally:
        await gw.stop()
