"""Planning on the map (SPEC §10, issue 34) against a real `fleet ground` and sim agents:
the API the planner uses (check, simulate in fast time against the live fleet, export
a `.plan`), then the planner in real Chromium — waypoints clicked, dragged, edited and
deleted, simulated, submitted and flown; two drones at once and a conflict refused;
a plan exported and loaded back.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio
from playwright.async_api import Browser, Page, expect

from bench.dashboard_frames import DESKTOP
from dronefleet.schemas.geo import destination, distance_m
from tests.dashboard.page import PLANS, SESSION_LOOP, UI_S, Dashboard
from tests.harness import GroundFleet, ended
from tests.waiting import until

pytestmark = [pytest.mark.integration, pytest.mark.xdist_group("chromium-planner"), SESSION_LOOP]
HOME = (40.633400, -8.660810)
SPAWNS = {"drone01": HOME, "drone02": destination(*HOME, 12, 90)}


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[GroundFleet]:
    fcs = {d: f"sim://?lat={lat}&lon={lon}&alt=8.2" for d, (lat, lon) in SPAWNS.items()}
    fleet = GroundFleet(tmp_path, fcs, {"telemetry_rate_ms": 100, "max_speed": 12})
    try:
        yield fleet
    finally:
        fleet.stop()


def square(n: int = 4, side: float = 20, start: tuple[float, float] = HOME) -> list[tuple[float, float]]:
    """Waypoints on a square north-east of `start`."""
    corners = [(side, 0), (side, side), (0, side), (side / 2, side / 2)]
    return [destination(*destination(*start, north, 0), east, 90) for north, east in corners[:n]]


def waypoint_script(points: list[tuple[float, float]], alt: float = 10) -> str:
    moves = "\n".join(f"move(d, lat={lat}, lon={lon}, alt=d.home.alt + {alt}*m, speed=6*m/s)" for lat, lon in points)
    return f'd = assign("drone01")\narm(d)\ntakeoff(d, {alt}*m)\n{moves}\nland(d)\n'


def nearest(path: list[list[float]], point: tuple[float, float]) -> float:
    return min(distance_m(p[1], p[2], point[0], point[1]) for p in path)


async def test_the_planner_api_checks_simulates_against_the_live_fleet_and_exports(fleet: GroundFleet) -> None:
    async with fleet.client() as http:
        bad = await http.post("/mission/check", content=b"arm(d)\nmove(d,\n")
        assert bad.status_code == 200 and not bad.json()["ok"]
        (problem,) = bad.json()["problems"]
        assert problem["kind"] == "syntax" and problem["line"] == 2, problem
        sandbox = (await http.post("/mission/check", content=b"import os\n")).json()
        assert sandbox["problems"][0]["kind"] == "security" and sandbox["problems"][0]["line"] == 1

        # Bad input: the field, or the line and column.
        r = await http.post("/mission/simulate", json={"source": "takeoff(\n"})
        assert r.status_code == 400 and r.json()["detail"]["line"] == 1, r.text
        r = await http.post("/mission/simulate", json={"source": "pass", "max_s": "long"})
        assert r.status_code == 400 and r.json()["detail"]["field"] == "$.max_s", r.text
        r = await http.post("/mission/simulate", json={"script": "pass"})
        assert r.status_code == 400 and "script" in r.json()["error"], r.text

        points = square()
        r = await http.post("/mission/simulate", json={"source": waypoint_script(points)}, timeout=200)
        assert r.status_code == 200, r.text
        predicted = r.json()
        assert (predicted["status"], predicted["cause"]) == ("finished", "success"), predicted
        drone = predicted["drones"]["drone01"]
        assert list(predicted["drones"]) == ["drone01"]
        for p in points:
            assert nearest(drone["path"], p) < 2.0, (p, nearest(drone["path"], p))
        assert drone["battery_start"] == 1.0 and drone["battery_end"] < 1.0 and drone["flying_s"] > 10
        assert drone["path"][0][1:3] == pytest.approx(list(HOME), abs=2e-5)  # where the live drone01 is
        assert predicted["duration_s"] > drone["flying_s"] > 0

        # Export: a plan QGroundControl opens, which imports back to the same waypoints.
        waypoints = [{"lat": lat, "lon": lon, "alt": 10.0 + i, "hold_s": float(i), "speed": 4.0 + i} for i, (lat, lon) in enumerate(points)]
        body: dict[str, Any] = {"waypoints": waypoints, "home": [HOME[0], HOME[1], 8.2], "takeoff_alt": 12, "end": "return"}
        r = await http.post("/mission/plan/export", json=body)
        assert r.status_code == 200 and "fleet.plan" in r.headers["content-disposition"], r.text
        plan = r.json()
        assert plan["fileType"] == "Plan" and plan["mission"]["version"] == 2
        assert plan["mission"]["plannedHomePosition"] == [HOME[0], HOME[1], 8.2]
        back = (await http.post("/mission/plan", content=json.dumps(plan).encode())).json()
        assert back["waypoints"] == waypoints
        assert (back["takeoff_alt"], back["end"], back["left_out"]) == (12, "return", [])
        r = await http.post("/mission/plan/export", json={**body, "waypoints": []})
        assert r.status_code == 400 and r.json()["detail"]["field"] == "$.waypoints", r.text
        r = await http.post("/mission/plan/export", json={**body, "end": "crash"})
        assert r.status_code == 400 and r.json()["detail"]["field"] == "$.end", r.text


@pytest_asyncio.fixture(loop_scope="session")
async def page(browser: Browser, tmp_path: Path, request: pytest.FixtureRequest) -> AsyncIterator[Page]:
    context = await browser.new_context(viewport=DESKTOP, accept_downloads=True)
    page = await context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    try:
        yield page
        assert not errors, errors
    finally:
        with contextlib.suppress(Exception):
            await page.screenshot(path=str(tmp_path / f"{request.node.name}.png"))
            print(f"screenshot: {tmp_path / f'{request.node.name}.png'}")
        await context.close()


async def open_planner(page: Page, url: str, drones: list[str]) -> None:
    await Dashboard(page).open(url)
    await page.wait_for_function("ids => ids.every(id => window.fleetDashboard.map.screenOf(id))", arg=drones,
                                 timeout=UI_S * 1000)
    await page.locator("#tab-plan").click()


async def zoom_to(page: Page, points: list[tuple[float, float]]) -> None:
    """Zoomed in until every point is on the map and 20 m are at least 60 px."""
    for _ in range(8):
        a, b = points[0], destination(*points[0], 20, 90)
        xa, _ = await page.evaluate("([lat, lon]) => window.fleetDashboard.map.toScreen(lat, lon)", list(a))
        xb, _ = await page.evaluate("([lat, lon]) => window.fleetDashboard.map.toScreen(lat, lon)", list(b))
        if xb - xa >= 60:
            break
        await page.locator("#zoom-in").click()
    box = await page.locator("#map").bounding_box()
    assert box is not None
    for p in points:
        x, y = await page.evaluate("([lat, lon]) => window.fleetDashboard.map.toScreen(lat, lon)", list(p))
        assert 10 < x < box["width"] - 10 and 10 < y < box["height"] - 10, ("off the map", p, x, y)


async def click_at(page: Page, point: tuple[float, float]) -> None:
    x, y = await page.evaluate("([lat, lon]) => window.fleetDashboard.map.toScreen(lat, lon)", list(point))
    await page.locator("#map").click(position={"x": x, "y": y})


async def plan_of(page: Page) -> dict[str, list[dict[str, float]]]:
    return dict(await page.evaluate("() => Object.fromEntries(window.fleetDashboard.planner.plans)"))


async def test_plan_four_waypoints_by_clicking_simulate_submit_and_fly_through_them(
    fleet: GroundFleet, page: Page, tmp_path: Path,
) -> None:
    points = square()
    async with fleet.client() as http:
        await open_planner(page, fleet.ground.url, ["drone01", "drone02"])
        await zoom_to(page, [HOME, *points])
        await page.locator("#plan-drone").select_option("drone01")
        await page.locator("#plan-add").click()
        stray = destination(*HOME, 8, 200)
        for p in [*points[:3], stray]:
            await click_at(page, p)
        await expect(page.locator("#plan-points tbody tr")).to_have_count(4, timeout=UI_S * 1000)
        # Delete the stray one, add the fourth; put the second 6 m off and drag it back.
        await page.locator("#plan-points button[data-delete='3']").click()
        off = destination(*points[1], 6, 270)
        await click_at(page, points[3])
        await page.evaluate("([lat, lon]) => { const p = window.fleetDashboard.planner.plans.get('drone01')[1]; "
                            "p.lat = lat; p.lon = lon; window.fleetDashboard.planner.changed(); }", list(off))
        x0, y0 = await page.evaluate("([lat, lon]) => window.fleetDashboard.map.toScreen(lat, lon)", list(off))
        x1, y1 = await page.evaluate("([lat, lon]) => window.fleetDashboard.map.toScreen(lat, lon)", list(points[1]))
        await page.locator("#plan-add").click()  # done adding: a drag must not add a point
        box = await page.locator("#map").bounding_box()
        assert box is not None
        await page.mouse.move(box["x"] + x0, box["y"] + y0)
        await page.mouse.down()
        await page.mouse.move(box["x"] + (x0 + x1) / 2, box["y"] + (y0 + y1) / 2, steps=4)
        await page.mouse.move(box["x"] + x1, box["y"] + y1, steps=4)
        await page.mouse.up()
        plan = await plan_of(page)
        assert len(plan["drone01"]) == 4
        for got, want in zip(plan["drone01"], points, strict=True):
            assert distance_m(got["lat"], got["lon"], *want) < 1.0, (got, want)
        # Altitude, speed and hold of a point; the script follows.
        await page.locator("input[data-index='0'][data-key='hold_s']").fill("2")
        await page.locator("input[data-index='0'][data-key='hold_s']").dispatch_event("change")
        await page.locator("input[data-index='2'][data-key='alt']").fill("14")
        await page.locator("input[data-index='2'][data-key='alt']").dispatch_event("change")
        script = await page.locator("#plan-script").input_value()
        assert script.count("move(d, ") == 4 and "sleep(2*s)" in script and "d.home.alt + 14*m" in script, script
        assert script.strip().endswith("land(d)")
        await expect(page.locator("#plan-status")).to_have_text("plan ok", timeout=UI_S * 1000)

        await page.locator("#plan-simulate").click()
        await expect(page.locator("#plan-status")).to_contain_text("predicted: finished", timeout=200_000)
        await expect(page.locator("#map")).to_have_attribute("data-predicted", "1", timeout=UI_S * 1000)
        left = await page.locator("#plan-result tr[data-drone='drone01'] .battery-left").inner_text()
        assert 50 < int(left.split()[0]) < 100, left
        assert await page.locator("#plan-chart").is_visible()
        await page.screenshot(path=str(tmp_path / "planner.png"))

        flown: list[tuple[float, float]] = []

        async def track() -> None:
            while True:
                r = await http.get("/drone/drone01", params={"data": "telem"})
                pos = r.json()["telem"]["position"] if r.status_code == 200 else None
                if pos:
                    flown.append((pos["lat"], pos["lon"]))
                await asyncio.sleep(0.1)

        tracker = asyncio.ensure_future(track())
        try:
            await page.locator("#plan-submit").click()
            await expect(page.locator("#plan-status")).to_contain_text("submitted as mission", timeout=UI_S * 1000)
            mission_id = await page.evaluate("() => window.fleetDashboard.planner.submitted")
            record = await ended(http, mission_id, 180)
        finally:
            tracker.cancel()
        assert (record["status"], record["cause"]) == ("finished", "success"), record
        for p in points:
            assert min(distance_m(*f, *p) for f in flown) < 2.0, p


async def test_two_drones_at_once_run_concurrently_and_a_conflict_is_refused_on_screen(fleet: GroundFleet, page: Page) -> None:
    one = square(2, 15)
    two = square(2, 15, SPAWNS["drone02"])
    two = [destination(*p, 10, 90) for p in two]
    async with fleet.client():
        await open_planner(page, fleet.ground.url, ["drone01", "drone02"])
        await zoom_to(page, [HOME, *one, *two])
        await page.locator("#plan-add").click()
        for drone, points in (("drone01", one), ("drone02", two)):
            await page.locator("#plan-drone").select_option(drone)
            for p in points:
                await click_at(page, p)
        script = await page.locator("#plan-script").input_value()
        assert "def fly_d1(d1):" in script and "def fly_d2(d2):" in script
        assert "wait(run(fly_d1, d1), run(fly_d2, d2))" in script, script
        await expect(page.locator("#plan-status")).to_have_text("plan ok", timeout=UI_S * 1000)
        await page.locator("#plan-simulate").click()
        await expect(page.locator("#plan-status")).to_contain_text("predicted: finished", timeout=200_000)
        predicted = await page.evaluate("() => window.fleetDashboard.planner.prediction")
        flying = {}
        for drone, d in predicted["drones"].items():
            airborne = [t for t, _lat, _lon, alt in d["path"] if alt > 1]
            flying[drone] = (min(airborne), max(airborne))
        assert set(flying) == {"drone01", "drone02"}
        (a0, a1), (b0, b1) = flying["drone01"], flying["drone02"]
        assert max(a0, b0) < min(a1, b1), flying  # both in the air at once: concurrent subroutines

        # drone02's next target 2 m from drone01's first, at the same altitude: refused, said why.
        await click_at(page, destination(*one[0], 2, 0))
        problems = page.locator("#plan-problems")
        await expect(problems).to_contain_text("targets conflict: drone01 waypoint 1 and drone02 waypoint 3", timeout=UI_S * 1000)
        await expect(page.locator("#plan-status")).to_have_text("the plan has problems")
        missions_before = await page.evaluate("() => window.fleetDashboard.fleet.missions.size")
        await page.locator("#plan-submit").click()
        await expect(problems).to_be_visible()
        assert await page.evaluate("() => window.fleetDashboard.planner.submitted") is None
        assert await page.evaluate("() => window.fleetDashboard.fleet.missions.size") == missions_before
        # A syntax error typed into the script is shown at its line.
        await page.locator("#plan-script").fill("d = assign('drone01')\narm(d\n")
        await expect(problems).to_contain_text("line 2", timeout=UI_S * 1000)


async def test_a_plan_exported_from_the_page_loads_back_to_the_same_waypoints(fleet: GroundFleet, page: Page, tmp_path: Path) -> None:
    points = square(3)
    async with fleet.client():
        await open_planner(page, fleet.ground.url, ["drone01"])
        await zoom_to(page, [HOME, *points])
        await page.locator("#plan-add").click()
        for p in points:
            await click_at(page, p)
        await page.locator("input[data-index='1'][data-key='speed']").fill("3")
        await page.locator("input[data-index='1'][data-key='speed']").dispatch_event("change")
        await page.locator("#plan-end").select_option("return")
        before = (await plan_of(page))["drone01"]
        async with page.expect_download() as download:
            await page.locator("#plan-export").click()
        saved = tmp_path / "drone01.plan"
        await (await download.value).save_as(saved)
        plan = json.loads(saved.read_text())
        assert plan["fileType"] == "Plan" and plan["mission"]["version"] == 2
        assert [i["command"] for i in plan["mission"]["items"]] == [22, 178, 16, 178, 16, 178, 16, 20]
        await page.locator("#plan-clear").click()
        await expect(page.locator("#plan-points tbody tr")).to_have_count(0)
        await page.locator("#plan-file").set_input_files(saved)
        await expect(page.locator("#plan-points tbody tr")).to_have_count(3, timeout=UI_S * 1000)
        after = (await plan_of(page))["drone01"]
        for a, b in zip(before, after, strict=True):
            assert (a["lat"], a["lon"], a["alt"], a["speed"], a["hold_s"]) == pytest.approx(
                (b["lat"], b["lon"], b["alt"], b["speed"], b["hold_s"]), abs=1e-7)
        assert await page.locator("#plan-end").input_value() == "return"
        # QGroundControl's own plan loads too, naming what it leaves out.
        await page.locator("#plan-file").set_input_files(PLANS / "PX4SITL-PX4-MultiRotor.plan")
        await expect(page.locator("#plan-status")).to_contain_text("imported 5 waypoints", timeout=UI_S * 1000)
        await expect(page.locator("#plan-status")).to_contain_text("item 5: MAV_CMD 195 is not carried over")


LANES_SCRIPT = '''d1, d2 = assign("drone01", "drone02")

def scout(d):
    arm(d)
    takeoff(d, 6*m)
    channel.ready = True
    move(d, forward=8*m)
    land(d)

def follow(d):
    go = channel.ready
    arm(d)
    takeoff(d, 9*m)
    land(d)

a = run(scout, d1)
b = run(follow, d2)
wait(a, b)
'''
LINE = {text.strip(): n for n, text in enumerate(LANES_SCRIPT.splitlines(), start=1)}


async def test_a_two_drone_mission_with_a_channel_shows_its_lanes_live(fleet: GroundFleet, page: Page, tmp_path: Path) -> None:
    """Each subroutine's line advancing, the wait on the channel, and both ending — in
    the page from /events, and in GET /mission/{id} for a page opened later."""
    async with fleet.client() as http:
        await open_planner(page, fleet.ground.url, ["drone01", "drone02"])
        await page.locator("#tab-missions").click()
        await page.locator("#mission-source").fill(LANES_SCRIPT)
        await page.locator("#mission-submit").click()
        await expect(page.locator("#mission-detail")).to_be_visible(timeout=UI_S * 1000)

        seen: dict[str, list[tuple[str, str]]] = {"scout": [], "follow": [], "main": []}

        async def lanes() -> list[dict[str, str]]:
            return list(await page.evaluate(
                "() => [...document.querySelectorAll('#lane-rows .lane')].map(r => ({...r.dataset, "
                "doing: r.querySelector('.lane-doing').textContent, drone: r.querySelector('.lane-drone').textContent, "
                "code: r.querySelector('.lane-code').textContent}))"))

        async def all_ended() -> bool:
            rows = await lanes()
            for row in rows:
                if row["name"] in seen and (not seen[row["name"]] or seen[row["name"]][-1] != (row["line"], row["doing"])):
                    seen[row["name"]].append((row["line"], row["doing"]))
                if row["name"] == "follow" and row["event"] == "waiting":
                    assert row["code"] == "go = channel.ready", row  # the script's line, shown in the lane
                    if not (tmp_path / "lanes.png").exists():
                        await page.locator("#mission-lanes").scroll_into_view_if_needed()
                        await page.screenshot(path=str(tmp_path / "lanes.png"))
            return len(rows) == 3 and all(r["event"] == "ended" for r in rows)

        await until(all_ended, 120, "every lane ended")
        rows = {r["name"]: r for r in await lanes()}
        assert {r["status"] for r in rows.values()} == {"finished"}, rows
        assert rows["scout"]["drone"] == "drone01" and rows["follow"]["drone"] == "drone02"
        # follow waited on the channel at its line, then went on once scout bound it.
        follow = seen["follow"]
        assert (str(LINE["go = channel.ready"]), "waiting on channel.ready") in follow, follow
        waited = follow.index((str(LINE["go = channel.ready"]), "waiting on channel.ready"))
        assert (str(LINE["takeoff(d, 9*m)"]), "takeoff") in follow[waited:], follow
        # scout's line advanced through its verbs in order.
        lines = [int(line) for line, _ in seen["scout"] if line]
        assert lines == sorted(lines) and {LINE["takeoff(d, 6*m)"], LINE["move(d, forward=8*m)"]} <= set(lines), seen["scout"]
        assert (str(LINE["wait(a, b)"]), "waiting on subroutine scout (s1), subroutine follow (s2)") in seen["main"], seen["main"]
        mission_id = await page.locator("#mission-list tr").first.get_attribute("data-mission")
        record = await ended(http, str(mission_id), 30)
        assert record["status"] == "finished" and record["source"] == LANES_SCRIPT
        by_name = {s["name"]: s for s in record["subroutines"]}
        assert set(by_name) == {"main", "scout", "follow"} and by_name["scout"]["parent"] == "s0"
        assert all(s["event"] == "ended" and s["status"] == "finished" for s in by_name.values()), by_name
