// The drones tab: one row per drone, and the selected drone's telemetry, sensors,
// link, current command, errors and warns, log, and command buttons. Every answer of
// the API to a command is shown, refusals first and loudest.

import { call } from "./api.js";
import { STATE_COLOURS, readingsText } from "./map.js";

const MESSAGES = 8;
const SENSOR_POLL_MS = 1000; // sensor readings are not in /events: the selected drone's are asked for

const $ = (id) => document.getElementById(id);

export class DronePanel {
  constructor(fleet, map, hooks) {
    this.fleet = fleet;
    this.map = map;
    this.hooks = hooks; // {redraw()}
    this.selected = null;
    this.rows = new Map();
    this.list = $("drone-list");
    this.detailShown = null;
    this.logShown = { id: null, first: null, count: 0 };
    this.logFetches = 0; // the latest fetch of the selected drone's log is the one that counts
    this.sensorText = "—";
    this.list.addEventListener("click", (e) => {
      const li = e.target.closest("li[data-drone]");
      if (li) this.select(li.dataset.drone);
    });
    for (const button of document.querySelectorAll("#commands button[data-cmd]")) {
      button.addEventListener("click", () => this.command(button.dataset.cmd));
    }
    $("pick-cancel").addEventListener("click", () => this.cancelPick());
    document.addEventListener("keydown", (e) => { if (e.key === "Escape") this.cancelPick(); });
    setInterval(() => this.pollSensors(), SENSOR_POLL_MS);
  }

  select(id) {
    if (this.selected === id) return;
    this.cancelPick();
    this.selected = id;
    this.selectedDrone = this.fleet.drones.get(id);
    this.map.selected = id;
    this.sensorText = "—";
    for (const [rid, li] of this.rows) li.classList.toggle("selected", rid === id);
    this.rows.get(id)?.scrollIntoView({ block: "nearest" });
    this.fleet.changed.add(id);
    this.loadLog();
    this.pollSensors();
    this.hooks.redraw();
  }

  /** After a (re)connection: the selected drone's log as the ground has it. */
  async loadLog() {
    const id = this.selected;
    if (!id) return;
    const fetch = ++this.logFetches;
    const sentAt = performance.now();
    const r = await call("GET", `/drone/logs?drone_id=${encodeURIComponent(id)}`);
    // Fetches cross (a reconnection and a drone coming back both ask): an older answer
    // arriving last would replace the newer one's lines, so only the latest is used.
    if (r.ok && this.selected === id && fetch === this.logFetches) {
      this.fleet.setDroneLog(id, r.data, sentAt);
      this.hooks.redraw();
    }
  }

  async pollSensors() {
    const id = this.selected;
    const d = id && this.fleet.drones.get(id);
    if (!d || !d.info?.sensors?.length || document.hidden) return;
    const r = await call("GET", `/drone/${encodeURIComponent(id)}?data=sensors`);
    if (!r.ok || this.selected !== id) return;
    const now = Date.now();
    this.sensorText = (r.data.sensors || []).map((s) =>
      `${readingsText(new Map([[s.type, s]]))} (${Math.max(0, (now - s.timestamp) / 1000).toFixed(0)} s ago)`,
    ).join(" · ") || "—";
    this.fleet.changed.add(id);
    this.hooks.redraw();
  }

  // ---- commands -----------------------------------------------------------------------

  command(cmd) {
    const id = this.selected;
    if (!id) return;
    if (cmd === "goto") {
      $("pick-hint").hidden = false;
      this.map.startPick((lat, lon) => {
        $("pick-hint").hidden = true;
        this.send(id, { cmd: "goto", lat: round(lat, 7), lon: round(lon, 7) });
      });
      return;
    }
    const body = { cmd };
    if (cmd === "takeoff") {
      const raw = $("takeoff-alt").value.trim();
      if (raw !== "") body.alt = Number(raw);
    }
    this.send(id, body);
  }

  cancelPick() {
    if (!this.map.pick) return;
    this.map.stopPick();
    $("pick-hint").hidden = true;
  }

  async send(id, body) {
    const what = body.cmd === "goto" ? `goto ${body.lat.toFixed(6)}, ${body.lon.toFixed(6)}` : body.alt !== undefined ? `${body.cmd} ${body.alt} m` : body.cmd;
    const r = await call("POST", `/drone/${encodeURIComponent(id)}/cmd`, { json: body });
    this.message(r.ok ? `${id}: ${what} accepted (command ${r.data.command_id.slice(0, 8)})` : `${id}: ${what}: ${r.message}`, !r.ok);
  }

  message(text, error) {
    const ol = $("cmd-messages");
    for (const li of ol.children) li.classList.add("old");
    const li = document.createElement("li");
    li.className = error ? "error" : "ok";
    li.textContent = `${new Date().toLocaleTimeString()} ${text}`;
    ol.prepend(li);
    while (ol.children.length > MESSAGES) ol.lastElementChild.remove();
  }

  // ---- rendering ----------------------------------------------------------------------

  render() {
    const fleet = this.fleet;
    if (fleet.membershipChanged) {
      this._rebuildList();
      const d = fleet.drones.get(this.selected);
      if (d && d !== this.selectedDrone) this.loadLog(); // it came back (a restarted ground): its log as the ground has it
      this.selectedDrone = d;
    }
    for (const id of fleet.changed) {
      const li = this.rows.get(id);
      if (li) this._renderRow(li, fleet.drones.get(id));
    }
    if (this.selected && (fleet.changed.has(this.selected) || this.detailShown !== this.selected || fleet.membershipChanged)) {
      this._renderDetail(fleet.drones.get(this.selected));
    }
  }

  _rebuildList() {
    const ids = this.fleet.sortedIds();
    const rows = new Map();
    const fragment = document.createDocumentFragment();
    for (const id of ids) {
      let li = this.rows.get(id);
      if (!li) {
        li = document.createElement("li");
        li.dataset.drone = id;
        li.innerHTML = '<span class="dot"></span><span class="id"></span><span class="st"></span><span class="num bat"></span><span class="num alt"></span>';
        li.children[1].textContent = id;
        li.cells = li.children;
        this._renderRow(li, this.fleet.drones.get(id));
      }
      li.classList.toggle("selected", id === this.selected);
      rows.set(id, li);
      fragment.append(li);
    }
    this.list.replaceChildren(fragment);
    this.rows = rows;
    $("drone-count").textContent = String(ids.length);
  }

  _renderRow(li, d) {
    const state = d.info?.state || "unknown";
    const t = d.telem;
    const c = li.cells;
    if (li.dataset.state !== state) {
      li.dataset.state = state;
      c[0].style.background = STATE_COLOURS[state] || STATE_COLOURS.unknown;
    }
    set(c[2], state + (d.info?.errors?.length ? " !" : ""));
    set(c[3], t?.battery ? `${Math.round(t.battery.remaining_percent * 100)}%` : "—");
    set(c[4], t?.position ? `${t.position.rel_alt.toFixed(1)} m` : "—");
  }

  _renderDetail(d) {
    const detail = $("drone-detail");
    if (!d) {
      detail.hidden = true;
      this.detailShown = null;
      return;
    }
    detail.hidden = false;
    this.detailShown = d.id;
    const info = d.info || {};
    const t = d.telem || {};
    const p = t.position;
    const state = info.state || "unknown";
    set($("detail-id"), d.id);
    set($("detail-state"), state);
    $("detail-dot").style.background = STATE_COLOURS[state] || STATE_COLOURS.unknown;
    set($("telem-alt"), p ? `${p.rel_alt.toFixed(1)} m` : "—");
    set($("telem-pos"), p ? `${p.lat.toFixed(6)}, ${p.lon.toFixed(6)}` : "—");
    set($("telem-amsl"), p ? `${p.alt.toFixed(1)} m` : "—");
    set($("telem-heading"), d.telem ? `${Math.round(t.heading)}°` : "—");
    const v = t.velocity || {};
    set($("telem-speed"), d.telem ? `${fmt(t.speed)} m/s (N ${fmt(v.north)}, E ${fmt(v.east)}, D ${fmt(v.down)})` : "—");
    set($("telem-battery"), t.battery ? `${Math.round(t.battery.remaining_percent * 100)}% · ${t.battery.voltage.toFixed(2)} V` : "—");
    set($("telem-mode"), t.flight_mode || "—");
    set($("telem-armed"), d.telem ? (t.armed ? "armed" : "disarmed") : "—");
    set($("telem-landed"), t.landed_state || "—");
    set($("telem-gps"), t.gps_info ? `${t.gps_info.fix_type} · ${t.gps_info.satellites} sats` : "—");
    set($("telem-home"), t.home ? `${t.home.lat.toFixed(6)}, ${t.home.lon.toFixed(6)}` : "—");
    set($("telem-seq"), d.telem ? `${t.seq} · ${Math.max(0, (Date.now() - t.timestamp) / 1000).toFixed(1)} s` : "—");
    const link = info.link;
    set($("link"), link ? `quality ${link.quality.toFixed(2)} · loss ${(link.loss * 100).toFixed(0)}%`
      + (link.rtt_ms != null ? ` · rtt ${link.rtt_ms.toFixed(0)} ms` : "")
      + (link.jitter_ms != null ? ` · jitter ${link.jitter_ms.toFixed(0)} ms` : "")
      + (link.hops != null ? ` · ${link.hops} hops` : "") : "not measured");
    const cmd = info.current_command;
    const bundle = info.bundle;
    set($("current-command"), (cmd ? cmd.description : "none") + (bundle ? ` · bundle ${bundle.bundle_id} step ${bundle.step + 1}/${bundle.steps}: ${bundle.description}` : ""));
    set($("drone-mission"), info.mission || "—");
    set($("drone-about"), info.kind ? `${info.kind} · ${(info.roles || []).join(", ")}` : "not declared yet");
    set($("drone-declares"), declared(info.sensors_declared));
    set($("sensors"), info.sensors?.length ? this.sensorText === "—" ? info.sensors.join(", ") : this.sensorText : "none");
    this._renderAlerts(info);
    this._renderLog(d);
  }

  _renderAlerts(info) {
    const key = JSON.stringify([info.errors, info.warns]);
    const ul = $("alerts");
    if (ul.dataset.key === key) return;
    ul.dataset.key = key;
    ul.replaceChildren(...[...(info.errors || []).map((m) => ["error", m]), ...(info.warns || []).map((m) => ["warn", m])].map(([level, m]) => {
      const li = document.createElement("li");
      li.className = level;
      li.textContent = `${level}: ${m}`;
      return li;
    }));
  }

  _renderLog(d) {
    const ol = $("drone-log");
    const shown = this.logShown;
    const stick = ol.scrollTop + ol.clientHeight >= ol.scrollHeight - 4;
    if (shown.id !== d.id || shown.first !== d.log[0] || shown.count > d.log.length) {
      ol.replaceChildren();
      shown.count = 0;
    }
    for (const line of d.log.slice(shown.count)) {
      const li = document.createElement("li");
      li.className = line.level;
      li.textContent = line.text;
      ol.append(li);
    }
    Object.assign(shown, { id: d.id, first: d.log[0], count: d.log.length });
    if (stick) ol.scrollTop = ol.scrollHeight;
  }
}

function set(el, text) {
  if (el.textContent !== text) el.textContent = text;
}

function fmt(x) {
  return typeof x === "number" ? x.toFixed(1) : "—";
}

function round(x, digits) {
  const k = 10 ** digits;
  return Math.round(x * k) / k;
}

/** What a drone declares of its sensors (SPEC §2 About): "gas (co_ppm ppm 0–1000)". */
function declared(sensors) {
  if (sensors == null) return "—";
  if (!sensors.length) return "none";
  const range = (d) => [d.unit, d.min != null || d.max != null ? `${d.min ?? ""}–${d.max ?? ""}` : ""].filter(Boolean).join(" ");
  return sensors.map((s) => {
    const inner = s.fields ? Object.entries(s.fields).map(([k, d]) => [k, range(d)].filter(Boolean).join(" ")).join(", ") : range(s);
    return inner ? `${s.type} (${inner})` : s.type;
  }).join(" · ");
}
