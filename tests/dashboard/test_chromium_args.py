"""The flags the dashboard's Chromium is launched with (bench/dashboard_frames.py):
they keep every feature the installed Playwright disables, and a window builds no
browser UI of its own (the omnibox popup cost 0.8 CPU-seconds per context)."""

from __future__ import annotations

import re
from pathlib import Path

import playwright
import pytest
from playwright.async_api import Browser

from bench.dashboard_frames import CHROMIUM_ARGS, DESKTOP, PLAYWRIGHT_DISABLED_FEATURES
from tests.dashboard.page import SESSION_LOOP


def playwright_disabled_features() -> set[str]:
    """The features the installed Playwright's driver passes in its --disable-features."""
    driver = Path(playwright.__file__).parent / "driver" / "package" / "lib"
    for source in sorted(driver.rglob("*.js")):
        text = source.read_text(errors="replace")
        if (found := re.search(r"disabledFeatures = \[(.*?)\]", text, re.S)) is not None:
            return set(re.findall(r'^\s*"(\w+)"', found.group(1), re.M))
    raise AssertionError(f"no disabledFeatures list in {driver}")


def test_the_launch_keeps_every_feature_playwright_disables() -> None:
    theirs = playwright_disabled_features()
    assert "PaintHolding" in theirs, theirs  # the parse found the list
    disabled = [arg for arg in CHROMIUM_ARGS if arg.startswith("--disable-features=")]
    assert len(disabled) == 1, disabled  # a second one would replace the first
    ours = set(disabled[0].removeprefix("--disable-features=").split(","))
    assert theirs <= ours, f"Playwright also disables {sorted(theirs - ours)}: add them to PLAYWRIGHT_DISABLED_FEATURES"
    assert set(PLAYWRIGHT_DISABLED_FEATURES) <= ours


@pytest.mark.integration
@pytest.mark.xdist_group("chromium")
@SESSION_LOOP
async def test_a_window_builds_no_browser_ui(browser: Browser) -> None:
    context = await browser.new_context(viewport=DESKTOP)
    try:
        await (await context.new_page()).goto("about:blank")
        session = await browser.new_browser_cdp_session()
        targets = (await session.send("Target.getTargets"))["targetInfos"]
        assert [t["url"] for t in targets if t["type"] == "page"] == ["about:blank"], targets
        assert not [t for t in targets if t["type"] == "browser_ui"], targets
    finally:
        await context.close()
