"""A real, headless browser for the tests: Debian's Chromium driven by selenium through Debian's
chromedriver (``bash tools/setup.sh test`` installs both; selenium's own driver download cannot
work offline, so the driver is given by path), and the processes a test leaves behind."""
from __future__ import annotations

import contextlib
import tempfile
import time
from pathlib import Path

import psutil

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"


@contextlib.contextmanager
def headless_chromium(*, width: int = 1600, height: int = 1000, extra_args=()):
    """``with headless_chromium() as driver:`` a selenium WebDriver on a fresh profile (and
    Chromium's ``extra_args``), quit on leaving; afterwards no process of that browser (its
    profile folder is in their command lines) is left running."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    with tempfile.TemporaryDirectory(prefix="talkingface-chromium-") as profile:
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage",
                    "--disable-gpu", f"--window-size={width},{height}",
                    f"--user-data-dir={profile}", *extra_args):
            options.add_argument(arg)
        driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
        try:
            yield driver
        finally:
            driver.quit()
            left = wait_gone(processes_mentioning(profile))
            assert not left, f"chromium outlived driver.quit(): {left}"


def processes_mentioning(text: str) -> list[psutil.Process]:
    """Running processes whose command line contains ``text``, and all their descendants."""
    found = {}
    for p in psutil.process_iter(["cmdline"]):
        with contextlib.suppress(psutil.Error):
            if text in " ".join(p.info["cmdline"] or ()):
                found[p.pid] = p
                for c in p.children(recursive=True):
                    found[c.pid] = c
    return list(found.values())


def alive_processes(procs) -> list[psutil.Process]:
    """The processes of ``procs`` still running (not finished, not a zombie, not a new process
    that reused the pid)."""
    out = []
    for p in procs:
        with contextlib.suppress(psutil.Error):
            if p.is_running() and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
    return out


def command_lines(procs) -> str:
    """The whole command lines of the processes of ``procs`` still running, joined by spaces
    (a process that ends or becomes a zombie meanwhile has none to read)."""
    out = []
    for p in alive_processes(procs):
        with contextlib.suppress(psutil.Error):
            out.append(" ".join(p.cmdline()))
    return " ".join(out)


def alive(procs) -> list[str]:
    """:func:`alive_processes` as ``"pid command line"``, for assertion messages."""
    out = []
    for p in alive_processes(procs):
        with contextlib.suppress(psutil.Error):
            out.append(f"{p.pid} {' '.join(p.cmdline())[:120]}")
    return out


def wait_gone(procs, timeout: float = 30.0) -> list[str]:
    """Wait up to ``timeout`` s for ``procs`` to end (zombies count as ended: their parent
    may reap them later); those still running then."""
    deadline = time.monotonic() + timeout
    while alive(procs) and time.monotonic() < deadline:
        time.sleep(0.2)
    return alive(procs)


def save_png(driver, folder: Path, name: str) -> Path:
    """A screenshot of the page into ``folder/name``."""
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / name
    assert driver.save_screenshot(str(out)), out
    return out


def page_headings(driver) -> list[str]:
    """The texts of the page's headings (``h1``-``h4`` and ``role=heading``), in page order."""
    return driver.execute_script(
        "return [...document.querySelectorAll('h1,h2,h3,h4,[role=heading]')]"
        ".map(e => e.textContent.trim()).filter(t => t)")


def local_storage(driver, key: str) -> str | None:
    """The raw value of ``key`` in the current page's localStorage (None: unset)."""
    return driver.execute_script("return window.localStorage.getItem(arguments[0])", key)


def set_local_storage(driver, url: str, items: dict) -> None:
    """Set localStorage ``items`` for the origin of ``url`` (a page of that origin that runs no
    script of its own, e.g. a server's health check), as a browser that stored them earlier."""
    driver.get(url)
    for key, value in items.items():
        driver.execute_script("window.localStorage.setItem(arguments[0], arguments[1])",
                              key, value)


def wait_until(driver, condition, what: str, timeout: float = 120.0):
    """``condition(driver)``'s first true value, polled every 0.5 s; after ``timeout`` s an
    AssertionError naming ``what`` with the page's address, headings and start of its text."""
    from selenium.common.exceptions import TimeoutException
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    try:
        return WebDriverWait(driver, timeout, poll_frequency=0.5).until(condition)
    except TimeoutException:
        text = driver.find_element(By.TAG_NAME, "body").text[:600].replace("\n", " | ")
        raise AssertionError(f"after {timeout:g} s, no {what}: at {driver.current_url}, "
                             f"headings {page_headings(driver)}, text: {text}") from None


def click(driver, element) -> None:
    """Scroll ``element`` to the middle of the window, then click it, as a person would."""
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'})", element)
    element.click()


def displayed_with_text(driver, text: str, tag: str = "*") -> list:
    """The displayed ``tag`` elements whose whole text (spaces normalised) is ``text``,
    innermost first (a label's own element before the boxes around it)."""
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.common.by import By

    literal = f"'{text}'" if "'" not in text else f'"{text}"'
    shown = []
    for e in driver.find_elements(By.XPATH, f"//{tag}[normalize-space(.)={literal}]"):
        with contextlib.suppress(StaleElementReferenceException):  # re-rendered meanwhile
            if e.is_displayed():
                shown.append(e)
    return shown[::-1]
