"""One headless Chromium per test session (per pytest-xdist worker), reset to a fresh
profile's state for every use: the browser tests of ``tests/talkingface`` open it some ten times
a run, and each new browser process cost ~2-3 s to start and quit on 2 loaded cores.

``with fresh_browser() as driver:`` (a fixture) gives the session's driver after clearing what a
page can leave in it: every origin's storage (localStorage, IndexedDB, cache storage, service
workers, cookies: Chrome DevTools ``Storage.clearDataForOrigin`` with origin ``*``), the HTTP
cache and the cookies, on ``about:blank``, in a window of the size asked for. So each ``with``
block starts as a browser that has never loaded a page (no stored MLflow workflow type, no
assistant-panel flag, nothing cached), as ``headless_chromium()`` with a new profile does
(``tests/talkingface/test_ui_landing.py`` checks it on two origins).
At the session's end the browser is quit, and no process of it may outlive that
(:func:`tests.talkingface.browser.headless_chromium`).

Used through ``pytest_plugins`` in ``tests/conftest.py``.
"""
from __future__ import annotations

import contextlib

import pytest

from tests.talkingface.browser import headless_chromium


def reset(driver, *, width: int, height: int) -> None:
    """Leave ``driver`` on ``about:blank`` with nothing stored by any page, in a window of
    ``width`` x ``height`` pixels."""
    for handle in driver.window_handles[1:]:  # windows a page opened
        driver.switch_to.window(handle)
        driver.close()
    driver.switch_to.window(driver.window_handles[0])
    driver.get("about:blank")
    driver.execute_cdp_cmd("Storage.clearDataForOrigin", {"origin": "*", "storageTypes": "all"})
    driver.execute_cdp_cmd("Network.clearBrowserCache", {})
    driver.execute_cdp_cmd("Network.clearBrowserCookies", {})
    driver.set_window_size(width, height)


@pytest.fixture(scope="session")
def _session_chromium():
    """The session's browser: ``[driver]``, replaced by :func:`fresh_browser` if it died."""
    with contextlib.ExitStack() as stack:
        drivers = []

        def start():
            drivers[:] = [stack.enter_context(headless_chromium())]
            return drivers[0]

        yield drivers, start


@pytest.fixture
def fresh_browser(_session_chromium):
    """``with fresh_browser(width=1600, height=1000) as driver:`` the session's Chromium in a
    fresh profile's state (:func:`reset`), left on ``about:blank`` afterwards."""
    from selenium.common.exceptions import WebDriverException

    drivers, start = _session_chromium

    @contextlib.contextmanager
    def use(*, width: int = 1600, height: int = 1000):
        driver = drivers[0] if drivers else start()
        try:
            reset(driver, width=width, height=height)
        except WebDriverException:  # the browser died in an earlier test: a new one
            driver = start()
            reset(driver, width=width, height=height)
        try:
            yield driver
        finally:
            with contextlib.suppress(WebDriverException):
                driver.get("about:blank")

    return use
