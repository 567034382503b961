"""The dashboard page as the tests drive it (Playwright on Debian's Chromium), and what
they share: the fleets' spawns and fence, the UI deadline."""

from __future__ import annotations

import asyncio
import os
import re
import shutil
from pathlib import Path
from typing import Any

import httpx
import pytest
from playwright.async_api import Error as PlaywrightError
from playwright.async_api import Page, Request, Route, ViewportSize, expect
from playwright.async_api import TimeoutError as PlaywrightTimeoutError

PLANS = Path(__file__).resolve().parents[1] / "plans"


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


PHONE = ViewportSize(width=390, height=844)


SCALE_JS = ("(parseFloat(document.querySelector('#scale-label').textContent) * "
            "(document.querySelector('#scale-label').textContent.endsWith('km') ? 1000 : 1) / "
            "document.querySelector('#scale-bar').getBoundingClientRect().width)")


# The dashboard tests run on the session's event loop, where their one Chromium lives (conftest.py).
SESSION_LOOP = pytest.mark.asyncio(loop_scope="session")


# Deadlines are generous: two cores run five pytest workers, Chromium and the drones.
UI_S = 30.0


SPAWNS = {"drone01": (40.633490, -8.660815), "drone02": (40.633590, -8.660815), "drone03": (40.633690, -8.660815)}


FENCE = [[40.634030, -8.661526], [40.634030, -8.660104], [40.632950, -8.660104], [40.632950, -8.661526]]  # 120 m square


def chromium() -> str:
    """Debian's chromium: a missing one fails the run as root (CI: `make sysdeps`
    installs it), and skips the test elsewhere."""
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        why = "chromium is not installed (Debian: `make sysdeps` as root, or apt-get install chromium)"
        if os.geteuid() == 0:
            pytest.fail(why)
        pytest.skip(why)
    return path


async def load(page: Page, url: str) -> None:
    """`page.goto(url)`, again when the load was aborted because the machine's network
    changed (the radio tests add and remove the laptop's link while pages load), as a
    person would reload; the page's own modules recover by themselves (index.html)."""
    for attempt in range(3):
        try:
            await page.goto(url)
            return
        except PlaywrightError as exc:
            if "ERR_NETWORK_CHANGED" not in str(exc) or attempt == 2:
                raise


class Dashboard:
    """One page of the dashboard, with what the tests read and do on it."""

    def __init__(self, page: Page) -> None:
        self.page = page
        self.errors: list[str] = []  # uncaught exceptions in the page
        self.console: list[str] = []  # what the page logged, for a failure's message
        self.pending: dict[Request, str] = {}  # requests sent and not answered yet
        page.on("pageerror", lambda exc: self.errors.append(str(exc)))
        page.on("console", lambda msg: self.console.append(f"{msg.type}: {msg.text}"))
        page.on("request", self._sent)
        page.on("requestfinished", self._answered)
        page.on("requestfailed", self._answered)

    def _sent(self, request: Request) -> None:
        self.pending[request] = f"{request.method} {request.url}"

    def _answered(self, request: Request) -> None:
        self.pending.pop(request, None)

    async def open(self, url: str) -> None:
        await load(self.page, url)
        # the first page of a run loads while every worker starts its processes: 30 s was missed
        try:
            await self.page.wait_for_function("() => window.fleetDashboard !== undefined", timeout=2 * UI_S * 1000)
        except PlaywrightTimeoutError:
            banner = await self.page.locator("#banner").text_content()
            raise AssertionError(
                f"the page at {url} did not come up in {2 * UI_S:g} s; banner {banner!r}; "
                f"unanswered requests {sorted(self.pending.values())}; console {self.console[-20:]}; "
                f"errors {self.errors}") from None

    async def metres_per_pixel(self) -> float:
        """What the scale bar says."""
        return float(await self.page.evaluate(f"() => {SCALE_JS}"))

    async def stats(self) -> dict[str, Any]:
        return dict(await self.page.evaluate("() => window.fleetDashboard.stats"))

    async def screen_of(self, drone_id: str) -> tuple[float, float]:
        xy = await self.page.evaluate("id => window.fleetDashboard.map.screenOf(id)", drone_id)
        assert xy is not None, f"{drone_id} is not on the map"
        return xy[0], xy[1]

    async def click_map(self, x: float, y: float) -> None:
        box = await self.page.locator("#map").bounding_box()
        assert box is not None
        assert 0 < x < box["width"] and 0 < y < box["height"], f"({x:.0f}, {y:.0f}) is off the map ({box})"
        await self.page.locator("#map").click(position={"x": x, "y": y})

    async def click_map_at(self, lat: float, lon: float) -> None:
        x, y = await self.page.evaluate("([lat, lon]) => window.fleetDashboard.map.toScreen(lat, lon)", [lat, lon])
        await self.click_map(x, y)

    async def command(self, cmd: str) -> str:
        """Press a command button; the message the page shows for its answer."""
        messages = self.page.locator("#cmd-messages li")
        before = await messages.count()
        await self.page.locator(f"#commands button[data-cmd={cmd}]").click()
        if cmd == "goto":
            return ""
        return await self.latest_message(before)

    async def latest_message(self, before: int) -> str:
        messages = self.page.locator("#cmd-messages li")
        if before < 8:
            await expect(messages).to_have_count(before + 1, timeout=UI_S * 1000)
        else:
            await expect(messages.first).not_to_have_class(re.compile("old"), timeout=UI_S * 1000)
        return await messages.first.inner_text()

    async def position(self) -> tuple[float, float]:
        """The selected drone's position as the panel shows it."""
        lat, lon = (await self.page.locator("#telem-pos").inner_text()).split(", ")
        return float(lat), float(lon)


async def served_from_the_package(http: httpx.AsyncClient) -> None:
    """The page and its files come from the ground with their types; nothing else is needed."""
    page = await http.get("/")
    assert page.headers["content-type"].startswith("text/html") and '<canvas id="map"' in page.text
    sources = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert sources and all(s.startswith("/dashboard/") or s.startswith("data:") for s in sources), sources
    for name, kind in (("main.js", "text/javascript"), ("map.js", "text/javascript"), ("style.css", "text/css")):
        asset = await http.get(f"/dashboard/{name}")
        assert asset.status_code == 200 and asset.headers["content-type"].startswith(kind), (name, asset.headers)
    for module in re.findall(r'from "\./([a-z_]+\.js)"', (await http.get("/dashboard/main.js")).text):
        assert (await http.get(f"/dashboard/{module}")).status_code == 200, module
    missing = await http.get("/dashboard/nothing.js")
    assert missing.status_code == 404 and "nothing.js" in missing.json()["error"]
    config = (await http.get("/dashboard/config.json")).json()
    assert config["geofence"]["polygon"] == FENCE and config["tiles"] is None and config["event_telemetry_ms"] == 500
    assert config["heat_sources"][0]["radius"] == 50 and config["ground_station"] is None
    assert (await http.get("/", headers={"accept": "application/json"})).json()["openapi"] == "/openapi.json"
    assert (await http.get("/openapi.json")).json()["info"]["title"] == "Fleet ground station"


class HeldAnswer:
    """The first request matching a pattern is answered with what the ground said when
    it came, but only once `release` is set; later ones go through: an older fetch
    whose answer arrives last."""

    def __init__(self) -> None:
        self.fetched, self.release = asyncio.Event(), asyncio.Event()
        self.requests = 0

    @classmethod
    async def on(cls, page: Page, pattern: re.Pattern[str]) -> HeldAnswer:
        held = cls()
        await page.route(pattern, held._handle)
        return held

    async def _handle(self, route: Route) -> None:
        self.requests += 1
        if self.requests > 1:
            await route.continue_()
            return
        response = await route.fetch()
        self.fetched.set()
        await self.release.wait()
        await route.fulfill(response=response)
