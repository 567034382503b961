// The dashboard's composition: load what the ground says to draw, connect to its
// events, and redraw in batches on animation frames — telemetry at most once per
// `event_telemetry_ms`, what the user does (pan, zoom, select) on the next frame.

import { call } from "./api.js";
import { DronePanel } from "./drones.js";
import { MapView, STATE_COLOURS } from "./map.js";
import { MissionPanel } from "./missions.js";
import { Planner } from "./planner.js";
import { Fleet } from "./store.js";
import { EventStream } from "./stream.js";
import { View } from "./view.js";

const $ = (id) => document.getElementById(id);
const WORK_SAMPLES = 600;
const FIELD_SENSORS_MS = 3000;
const GROUNDS_MS = 3000; // which ground is active (SPEC §14), asked again this often
const CONFIG_TIMEOUT_MS = 5000; // the first request: unanswered, the page asks again (and says so)

async function loadConfig() {
  for (let attempt = 1; ; attempt++) {
    const r = await call("GET", "/dashboard/config.json", { timeoutMs: CONFIG_TIMEOUT_MS });
    if (r.ok) return r.data;
    showDown(attempt, r.message);
    await new Promise((resolve) => setTimeout(resolve, Math.min(2000, 250 * attempt)));
  }
}

function showDown(attempt, why = "") {
  const banner = $("banner");
  banner.textContent = `Ground unreachable — reconnecting… (attempt ${attempt})${why ? ` · ${why}` : ""}`;
  banner.hidden = false;
  const conn = $("conn");
  conn.textContent = "reconnecting";
  conn.className = "conn down";
}

/** The grounds on the mesh (GET /ground): this one's role and epoch in the header,
 * and while it is standby, a notice that commands go to the active one. */
function showGrounds(grounds) {
  const me = grounds.find((g) => g.this);
  if (!me) return;
  const active = grounds.find((g) => g.active);
  const role = (g) => (g.active ? `active · epoch ${g.epoch}` : g.role === "observer" ? "observer" : "standby");
  const others = grounds.filter((g) => !g.this).map((g) => `${g.ground_id} ${role(g).replace(" ·", ",")}`);
  const label = $("ground");
  label.textContent = `ground ${me.ground_id} · ${role(me)}` + (others.length ? ` · also ${others.join(", ")}` : "");
  label.className = me.active ? "" : "standby";
  const notice = $("standby");
  notice.hidden = me.active;
  if (me.active) return;
  notice.textContent = `${me.role === "observer" ? "Observer" : "Standby"} ground: everything is shown, commands are refused here. `;
  if (active) {
    notice.append(`The active ground is ${active.ground_id} (epoch ${active.epoch})`);
    if (active.http) {
      const link = document.createElement("a");
      link.href = active.http;
      link.textContent = active.http;
      notice.append(" at ", link);
    }
    notice.append(".");
  } else {
    notice.append("No ground is active yet.");
  }
}

function showUp() {
  $("banner").hidden = true;
  const conn = $("conn");
  conn.textContent = "live";
  conn.className = "conn";
}

/** Redraws on animation frames: `urgent` ones (the user acted) on the next frame,
 * the others (new data) no sooner than `capMs` after the last one. */
class Frames {
  constructor(capMs, draw) {
    this.capMs = capMs;
    this.draw = draw;
    this.last = -Infinity;
    this.frame = 0; // requestAnimationFrame handle
    this.timer = 0;
    this.stats = { frames: 0, work: [] };
  }

  request(urgent = false) {
    if (this.frame) return;
    const wait = urgent ? 0 : this.last + this.capMs - performance.now();
    if (wait <= 0) {
      clearTimeout(this.timer);
      this.timer = 0;
      this.frame = requestAnimationFrame(() => this.run());
    } else if (!this.timer) {
      this.timer = setTimeout(() => {
        this.timer = 0;
        this.request(true);
      }, wait);
    }
  }

  run() {
    this.frame = 0;
    const t0 = performance.now();
    this.last = t0;
    this.draw();
    const work = this.stats.work;
    work.push(performance.now() - t0);
    if (work.length > WORK_SAMPLES) work.splice(0, work.length - WORK_SAMPLES);
    this.stats.frames++;
  }
}

function setupTabs(frames) {
  const tabs = [...document.querySelectorAll("#tabs button")];
  for (const tab of tabs) {
    tab.addEventListener("click", () => {
      for (const t of tabs) {
        const on = t === tab;
        t.setAttribute("aria-selected", String(on));
        $(`pane-${t.dataset.tab}`).hidden = !on;
      }
      frames.request(true);
    });
  }
}

function setupLegend() {
  $("legend").replaceChildren(...Object.entries(STATE_COLOURS).map(([state, colour]) => {
    const span = document.createElement("span");
    span.innerHTML = `<span class="dot" style="background:${colour}"></span>`;
    span.append(state);
    return span;
  }));
}

async function main() {
  const config = await loadConfig();
  const view = new View(config.tiles ? "mercator" : "local");
  const fleet = new Fleet(view);
  let drones = null;
  let missions = null;
  let map = null;
  let planner = null;

  const frames = new Frames(config.event_telemetry_ms, () => {
    map.draw();
    drones.render();
    missions.render();
    planner.renderDrones();
    fleet.changed.clear();
    fleet.membershipChanged = false;
    fleet.telemetryChanged = false;
    renderSummary(fleet);
  });
  const redraw = () => frames.request(true);
  map = new MapView($("map"), view, fleet, config, {
    redraw,
    select: (id) => drones.select(id),
    followOff: () => {
      $("follow").checked = false;
      map.follow = false;
    },
  });
  drones = new DronePanel(fleet, map, { redraw });
  missions = new MissionPanel(fleet, { redraw });
  planner = new Planner(fleet, map, config, { redraw });
  setupTabs(frames);
  setupLegend();

  $("zoom-in").addEventListener("click", () => map.zoom(1));
  $("zoom-out").addEventListener("click", () => map.zoom(-1));
  $("fit").addEventListener("click", () => {
    map.autoFit = true;
    map.fitted = false;
    redraw();
  });
  $("follow").addEventListener("change", (e) => {
    map.follow = e.target.checked;
    redraw();
  });
  new ResizeObserver(() => {
    map.resize();
    if (map.autoFit) map.fitted = false;
    redraw();
  }).observe($("map-pane"));
  map.resize();
  // The selected drone's "age" of telemetry keeps counting when nothing arrives.
  setInterval(() => {
    if (drones.selected) fleet.changed.add(drones.selected);
    frames.request();
  }, 1000);

  const data = () => frames.request();
  // Field sensors come with their readings on /events; which of them timed out, the
  // ground's list says (asked again every FIELD_SENSORS_MS).
  const loadFieldSensors = async () => {
    const r = await call("GET", "/sensor");
    if (r.ok) {
      fleet.resyncFieldSensors(r.data);
      data();
    }
  };
  setInterval(() => { if (!document.hidden) loadFieldSensors(); }, FIELD_SENSORS_MS);
  const loadGrounds = async () => {
    const r = await call("GET", "/ground");
    if (r.ok) showGrounds(r.data);
  };
  setInterval(() => { if (!document.hidden) loadGrounds(); }, GROUNDS_MS);
  const stream = new EventStream("/events", {
    telemetry: (t) => { fleet.stats.events++; fleet.onTelemetry(t); data(); },
    drone: (info) => { fleet.stats.events++; fleet.onDrone(info); data(); },
    log: (line) => { fleet.stats.events++; fleet.onLog(line); data(); },
    status: () => { fleet.stats.events++; },
    mission: (record) => { fleet.stats.events++; fleet.onMission(record); data(); },
    mission_log: (line) => { fleet.stats.events++; fleet.onMissionLog(line); data(); },
    field_sensor: (reading) => { fleet.stats.events++; fleet.onFieldSensor(reading); data(); },
    subroutine: (activity) => { fleet.stats.events++; fleet.onSubroutine(activity); data(); },
  }, {
    onOpen: async () => {
      showUp();
      const epoch = ++fleet.epoch;
      const [views] = await Promise.all([call("GET", "/drone"), missions.reload(), drones.loadLog(), loadFieldSensors(),
        loadGrounds()]);
      if (views.ok && epoch === fleet.epoch) fleet.resync(views.data, epoch);
      redraw();
    },
    onDown: (failures) => {
      showDown(failures);
      redraw();
    },
  });
  stream.start();

  sessionStorage.removeItem("fleet-load-attempt"); // loaded: the next failure waits from the start (index.html)
  // For people poking at the page from the console, and for the browser tests.
  window.fleetDashboard = {
    config, view, fleet, map, drones, missions, planner, stream,
    get stats() {
      return { ...fleet.stats, frames: frames.stats.frames, work: frames.stats.work, connections: stream.connections };
    },
  };
  redraw();
}

function renderSummary(fleet) {
  let flying = 0;
  let alerts = 0;
  for (const d of fleet.drones.values()) {
    if (d.telem?.armed && d.telem.landed_state !== "on_ground") flying++;
    if (d.info?.errors?.length) alerts++;
  }
  const text = `${fleet.drones.size} drones · ${flying} flying${alerts ? ` · ${alerts} in error` : ""}`;
  const el = $("summary");
  if (el.textContent !== text) el.textContent = text;
  const count = String(fleet.drones.size);
  if ($("drone-count").textContent !== count) $("drone-count").textContent = count;
}

main();
