// The missions tab: submit a script (pasted or uploaded), see why it does not compile
// (at its line and column), the list of missions with status and cause, one
// mission's live log, and cancel it.

import { call } from "./api.js";
import { MissionLanes, renderLanes } from "./lanes.js";

const ENDED = new Set(["finished", "failed", "cancelled"]);
const $ = (id) => document.getElementById(id);

export class MissionPanel {
  constructor(fleet, hooks) {
    this.fleet = fleet;
    this.hooks = hooks; // {redraw()}
    this.selected = null;
    this.rows = new Map();
    this.logShown = { id: null, count: 0 };
    this.loads = 0;
    this.latestLoad = new Map(); // mission id -> the number of its latest fetch
    $("mission-form").addEventListener("submit", (e) => {
      e.preventDefault();
      this.submit();
    });
    $("mission-file").addEventListener("change", async (e) => {
      const file = e.target.files[0];
      if (!file) return;
      e.target.value = "";
      if (file.name.toLowerCase().endsWith(".plan")) {
        await this.importPlan(file);
        return;
      }
      $("mission-import").hidden = true;
      $("mission-source").value = await file.text();
      $("mission-name").value = file.name;
    });
    $("mission-list").addEventListener("click", (e) => {
      const tr = e.target.closest("tr[data-mission]");
      if (tr) this.select(tr.dataset.mission);
    });
    $("mission-cancel").addEventListener("click", () => this.cancel());
  }

  /** After a (re)connection: every record, and the open mission's whole log. */
  async reload() {
    const sentAt = performance.now();
    const r = await call("GET", "/mission");
    if (!r.ok) return;
    for (const record of r.data) this.fleet.onMission(record, sentAt);
    if (this.selected) await this.load(this.selected);
    this.hooks.redraw();
  }

  async select(id) {
    this.selected = id;
    this.logShown = { id: null, count: 0 };
    for (const [rid, tr] of this.rows) tr.classList.toggle("selected", rid === id);
    $("mission-notice")?.remove();
    await this.load(id);
    this.fleet.missionsChanged.add(id);
    this.hooks.redraw();
  }

  async load(id) {
    this.fleet.watchMission(id);
    const fetch = ++this.loads;
    this.latestLoad.set(id, fetch);
    const sentAt = performance.now();
    const r = await call("GET", `/mission/${encodeURIComponent(id)}`);
    // As for a drone's log (drones.js loadLog): an older answer arriving last is stale.
    if (!r.ok || this.latestLoad.get(id) !== fetch) return;
    const { log, source, subroutines, marks, ...record } = r.data;
    this.fleet.setMissionLog(id, log, sentAt);
    if (!this.fleet.lanes.has(id)) this.fleet.lanes.set(id, new MissionLanes());
    this.fleet.lanes.get(id).seed({ source, subroutines, marks });
    this.fleet.onMission(record, sentAt);
    if (this.selected === id) this.logShown = { id: null, count: 0 };
  }

  /** A QGroundControl plan (SPEC §13): the ground turns it into a script, shown here to
   *  edit and submit, with every item it could not carry over named. */
  async importPlan(file) {
    const box = $("mission-error");
    const notes = $("mission-import");
    box.hidden = true;
    notes.hidden = true;
    const r = await call("POST", "/mission/plan", { text: await file.text() });
    if (!r.ok) {
      box.textContent = `${file.name}: ${r.message}`;
      box.hidden = false;
      return;
    }
    $("mission-source").value = r.data.script;
    $("mission-name").value = file.name.replace(/\.plan$/i, "");
    const lines = [`${file.name}: imported as a script`];
    if (r.data.geofence) lines.push("its inclusion fence is not applied here: add it to the ground's geofence");
    for (const line of r.data.left_out) lines.push(`not carried over: ${line}`);
    notes.replaceChildren(...lines.map((text) => Object.assign(document.createElement("div"), { textContent: text })));
    notes.hidden = false;
  }

  async submit() {
    const source = $("mission-source").value;
    const name = $("mission-name").value.trim();
    const box = $("mission-error");
    box.hidden = true;
    const sentAt = performance.now();
    const r = await call("POST", `/mission?name=${encodeURIComponent(name)}`, { text: source });
    if (r.ok) {
      const id = r.data.mission_id;
      if (!this.fleet.missions.has(id)) this.fleet.onMission({ mission_id: id, name, status: "pending", used_drones: [] }, sentAt);
      await this.select(id);
      return;
    }
    const detail = (r.data && r.data.detail) || {};
    box.replaceChildren();
    if (detail.line != null) {
      const head = document.createElement("div");
      head.textContent = `${detail.kind === "security" ? "Not allowed" : "Does not compile"} at line ${detail.line}, column ${detail.column}: ${detail.message}`;
      const lines = source.split("\n");
      const pre = document.createElement("pre");
      const text = lines[detail.line - 1] ?? "";
      pre.textContent = `${String(detail.line).padStart(4)} | ${text}\n       ${" ".repeat(Math.max(0, (detail.column || 1) - 1))}^`;
      box.append(head, pre);
      const at = lines.slice(0, detail.line - 1).reduce((n, l) => n + l.length + 1, 0) + Math.max(0, (detail.column || 1) - 1);
      $("mission-source").setSelectionRange(at, at);
    } else {
      box.textContent = r.message;
    }
    box.hidden = false;
  }

  async cancel() {
    const id = this.selected;
    if (!id) return;
    const sentAt = performance.now();
    const r = await call("DELETE", `/mission/${encodeURIComponent(id)}`);
    const p = $("mission-notice") || document.createElement("p");
    p.id = "mission-notice";
    p.className = r.ok ? "" : "error";
    p.textContent = r.ok ? `cancel of ${id} requested` : `cancel of ${id}: ${r.message}`;
    $("mission-message").after(p);
    if (r.ok) this.fleet.onMission(r.data, sentAt);
    this.hooks.redraw();
  }

  // ---- rendering ----------------------------------------------------------------------

  render() {
    const changed = this.fleet.missionsChanged;
    if (!changed.size) return;
    const tbody = $("mission-list");
    for (const id of changed) {
      const record = this.fleet.missions.get(id);
      if (!record) continue;
      let tr = this.rows.get(id);
      if (!tr) {
        tr = document.createElement("tr");
        tr.dataset.mission = id;
        tr.innerHTML = "<td></td><td></td><td></td><td></td><td></td>";
        this.rows.set(id, tr);
        const newer = [...this.rows.keys()].filter((k) => order(k) > order(id)).sort((a, b) => order(a) - order(b))[0];
        tbody.insertBefore(tr, newer ? this.rows.get(newer).nextSibling : tbody.firstChild);
      }
      tr.classList.toggle("selected", id === this.selected);
      const cells = tr.children;
      set(cells[0], id);
      set(cells[1], record.name || "");
      set(cells[2], record.status);
      cells[2].className = `s-${record.status}`;
      set(cells[3], record.cause || "");
      set(cells[4], (record.used_drones || []).join(", "));
    }
    const running = [...this.fleet.missions.values()].filter((m) => !ENDED.has(m.status)).length;
    set($("mission-count"), running ? `${this.fleet.missions.size} (${running} running)` : String(this.fleet.missions.size));
    if (this.selected && changed.has(this.selected)) this._renderDetail(this.fleet.missions.get(this.selected));
    changed.clear();
  }

  _renderDetail(record) {
    if (!record) return;
    $("mission-detail").hidden = false;
    set($("mission-id"), `${record.mission_id}${record.name ? ` · ${record.name}` : ""}`);
    set($("mission-status"), record.status);
    $("mission-status").className = `state s-${record.status}`;
    set($("mission-cause"), record.cause ? `cause: ${record.cause}` : "");
    set($("mission-message"), record.message || "");
    $("mission-cancel").disabled = ENDED.has(record.status);
    renderLanes(this.fleet.lanes.get(record.mission_id), record);
    const lines = this.fleet.missionLog(record.mission_id);
    const ol = $("mission-log");
    const stick = ol.scrollTop + ol.clientHeight >= ol.scrollHeight - 4;
    const shown = this.logShown;
    // Lines usually arrive in time order: append them; anything else redraws the list.
    if (shown.id !== record.mission_id || shown.count > lines.length || (shown.count && lines[shown.count - 1] !== shown.last)) {
      ol.replaceChildren();
      shown.count = 0;
    }
    for (const line of lines.slice(shown.count)) {
      const li = document.createElement("li");
      li.className = line.drone ? `${line.level} drone` : line.level;
      li.textContent = `${new Date(line.timestamp).toLocaleTimeString()} ${line.message}`;
      ol.append(li);
    }
    this.logShown = { id: record.mission_id, count: lines.length, last: lines[lines.length - 1] };
    if (stick) ol.scrollTop = ol.scrollHeight;
  }
}

function order(id) {
  const n = Number(String(id).replace(/^\D+/, ""));
  return Number.isFinite(n) ? n : 0;
}

function set(el, text) {
  if (el.textContent !== text) el.textContent = text;
}
