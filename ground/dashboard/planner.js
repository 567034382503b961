// The planner (SPEC §10): waypoints per drone set on the map become a mission script in
// the DSL, shown and editable beside the map and checked as it changes (syntax and
// sandbox at the ground; fence and the separation of targets here); *simulate* flies it
// in fast time on the ground against the live fleet and draws the predicted paths, time
// and battery; *submit* flies it; a plan is saved as its script or as a QGroundControl
// `.plan`, and a `.plan` is imported back into waypoints.

import { call } from "./api.js";

const $ = (id) => document.getElementById(id);
const COLOURS = ["#0b7a75", "#c2410c", "#6d28d9", "#0369a1", "#a16207", "#be185d"];
const GRAB_PX = 10;
const CHECK_MS = 300;
const R = 6371008.8;

export class Planner {
  constructor(fleet, map, config, hooks) {
    this.fleet = fleet;
    this.map = map;
    this.config = config;
    this.hooks = hooks; // {redraw()}
    this.plans = new Map(); // drone id → [{lat, lon, alt, speed, hold_s}]
    this.adding = false; // clicks on the map add waypoints to the chosen drone
    this.prediction = null; // the ground's last answer to simulate
    this.problems = [];
    this.checks = 0;
    this.checkTimer = 0;
    this.fence = (config.geofence.polygon || []).map(([lat, lon]) => ({ lat, lon }));
    this.separation = config.geofence.min_separation_m ?? 5;
    map.overlay = this;
    $("plan-add").addEventListener("click", () => this.setAdding(!this.adding));
    for (const id of ["plan-takeoff", "plan-end"]) $(id).addEventListener("change", () => this.changed());
    $("plan-points").addEventListener("change", (e) => this.edit(e.target));
    $("plan-points").addEventListener("click", (e) => {
      const button = e.target.closest("button[data-delete]");
      if (button) this.remove(button.dataset.drone, Number(button.dataset.delete));
    });
    $("plan-script").addEventListener("input", () => this.scheduleCheck());
    $("plan-simulate").addEventListener("click", () => this.simulate());
    $("plan-submit").addEventListener("click", () => this.submit());
    $("plan-export").addEventListener("click", () => this.exportPlan());
    $("plan-save").addEventListener("click", () => download("plan.py", $("plan-script").value, "text/x-python"));
    $("plan-clear").addEventListener("click", () => { this.plans.clear(); this.changed(); });
    $("plan-file").addEventListener("change", async (e) => {
      const file = e.target.files[0];
      e.target.value = "";
      if (file) await this.load(file);
    });
  }

  /** The drones the page knows, in the drone chooser (kept when the fleet changes). */
  renderDrones() {
    const select = $("plan-drone");
    const ids = this.fleet.sortedIds();
    if (select.options.length === ids.length && ids.every((id, i) => select.options[i].value === id)) return;
    const chosen = select.value;
    select.replaceChildren(...ids.map((id) => new Option(id, id)));
    if (ids.includes(chosen)) select.value = chosen;
  }

  setAdding(on) {
    this.adding = on;
    $("plan-add").classList.toggle("on", on);
    $("plan-add").textContent = on ? "Done adding" : "Add waypoints…";
    this.map.canvas.classList.toggle("picking", on);
  }

  // ---- the map overlay (map.js calls these) -------------------------------------------

  click(lat, lon) {
    const drone = $("plan-drone").value;
    if (!this.adding || !drone) return false;
    const points = this.plans.get(drone) || [];
    const last = points[points.length - 1];
    points.push({ lat, lon, alt: last?.alt ?? Number($("plan-takeoff").value || 10), speed: last?.speed ?? 5, hold_s: 0 });
    this.plans.set(drone, points);
    this.changed();
    return true;
  }

  grab(sx, sy) {
    for (const [drone, points] of this.plans) {
      for (const p of points) {
        const [x, y] = this.map.view.toScreen(p.lat, p.lon);
        if (Math.hypot(x - sx, y - sy) <= GRAB_PX) {
          return (lat, lon) => { p.lat = lat; p.lon = lon; this.changed(drone); };
        }
      }
    }
    return null;
  }

  draw(ctx, view) {
    let i = 0;
    const order = [...this.plans.keys()];
    for (const [drone, points] of this.plans) {
      const colour = COLOURS[order.indexOf(drone) % COLOURS.length];
      const start = this.fleet.drones.get(drone)?.telem?.position;
      const line = [...(start ? [start] : []), ...points].map((p) => view.toScreen(p.lat, p.lon));
      ctx.strokeStyle = colour;
      ctx.lineWidth = 2;
      ctx.setLineDash([]);
      strokePath(ctx, line);
      points.forEach((p, n) => {
        const [x, y] = view.toScreen(p.lat, p.lon);
        ctx.fillStyle = this.problemAt(drone, n) ? "#dc2626" : colour;
        ctx.beginPath();
        ctx.arc(x, y, 7, 0, 2 * Math.PI);
        ctx.fill();
        ctx.fillStyle = "#fff";
        ctx.font = "bold 10px sans-serif";
        ctx.textAlign = "center";
        ctx.textBaseline = "middle";
        ctx.fillText(String(n + 1), x, y + 0.5);
      });
      i++;
    }
    for (const [drone, predicted] of Object.entries(this.prediction?.drones || {})) {
      ctx.strokeStyle = COLOURS[Math.max(0, order.indexOf(drone)) % COLOURS.length];
      ctx.lineWidth = 1.5;
      ctx.setLineDash([5, 4]);
      strokePath(ctx, predicted.path.map(([, lat, lon]) => view.toScreen(lat, lon)));
      ctx.setLineDash([]);
      const last = predicted.path[predicted.path.length - 1];
      if (last) { // where it ends: the time flying and the battery left
        const [x, y] = view.toScreen(last[1], last[2]);
        const left = predicted.battery_end == null ? "" : ` · ${Math.round(predicted.battery_end * 100)} %`;
        ctx.fillStyle = "#1d2129";
        ctx.font = "11px sans-serif";
        ctx.textAlign = "left";
        ctx.fillText(`${drone} ${predicted.flying_s.toFixed(0)} s${left}`, x + 9, y - 9);
      }
    }
    this.map.canvas.dataset.planPoints = String([...this.plans.values()].reduce((n, p) => n + p.length, 0));
    this.map.canvas.dataset.predicted = String(Object.keys(this.prediction?.drones || {}).length);
    return i;
  }

  // ---- editing --------------------------------------------------------------------------

  edit(input) {
    const { drone, index, key } = input.dataset;
    const point = this.plans.get(drone)?.[Number(index)];
    if (!point) return;
    const value = Number(input.value);
    if (!Number.isFinite(value) || value < 0) return;
    point[key] = value;
    this.changed();
  }

  remove(drone, index) {
    const points = this.plans.get(drone) || [];
    points.splice(index, 1);
    if (!points.length) this.plans.delete(drone);
    this.changed();
  }

  changed() {
    this.prediction = null;
    $("plan-script").value = this.script();
    this.renderPoints();
    this.renderPrediction();
    this.scheduleCheck();
    this.hooks.redraw();
  }

  renderPoints() {
    const rows = [];
    for (const [drone, points] of this.plans) {
      points.forEach((p, n) => {
        const tr = document.createElement("tr");
        tr.dataset.drone = drone;
        const cell = (key, value, step) =>
          `<td><input type="number" min="0" step="${step}" value="${value}" data-drone="${drone}" data-index="${n}" data-key="${key}" aria-label="${key} of ${drone} waypoint ${n + 1}"></td>`;
        tr.innerHTML = `<td>${drone}</td><td>${n + 1}</td>${cell("alt", p.alt, 1)}${cell("speed", p.speed, 0.5)}${cell("hold_s", p.hold_s, 1)}`
          + `<td><button type="button" data-drone="${drone}" data-delete="${n}" title="delete">✕</button></td>`;
        rows.push(tr);
      });
    }
    $("plan-points").querySelector("tbody").replaceChildren(...rows);
  }

  /** The plan as a mission script: one subroutine per drone when several fly. */
  script() {
    if (!this.plans.size) return "";
    const takeoff = Number($("plan-takeoff").value || 10);
    const end = $("plan-end").value;
    const several = this.plans.size > 1;
    const out = [`"""Planned on the map: ${[...this.plans].map(([d, p]) => `${d} (${p.length} waypoints)`).join(", ")}."""`];
    const body = (d, points, pad) => {
      const lines = [`arm(${d})`, `takeoff(${d}, ${fmt(takeoff)}*m)`];
      for (const p of points) {
        lines.push(`move(${d}, lat=${p.lat.toFixed(7)}, lon=${p.lon.toFixed(7)}, alt=${d}.home.alt + ${fmt(p.alt)}*m, speed=${fmt(p.speed)}*m/s)`);
        if (p.hold_s > 0) lines.push(`sleep(${fmt(p.hold_s)}*s)`);
      }
      if (end === "land") lines.push(`land(${d})`);
      else if (end === "return") lines.push(`home(${d})`);
      return lines.map((l) => pad + l);
    };
    const names = [...this.plans.keys()].map((id, i) => (several ? `d${i + 1}` : "d"));
    out.push(`${names.join(", ")} = assign(${[...this.plans.keys()].map((id) => JSON.stringify(id)).join(", ")})`);
    if (!several) return [...out, ...body("d", this.plans.get([...this.plans.keys()][0]), "")].join("\n") + "\n";
    const runs = [];
    [...this.plans.values()].forEach((points, i) => {
      out.push("", `def fly_${names[i]}(${names[i]}):`, ...body(names[i], points, "    "));
      runs.push(`run(fly_${names[i]}, ${names[i]})`);
    });
    out.push("", `wait(${runs.join(", ")})`);
    return out.join("\n") + "\n";
  }

  // ---- checks -----------------------------------------------------------------------------

  /** What this page can see: targets outside the fence, targets of two drones too close. */
  localProblems() {
    const found = [];
    const all = [...this.plans].flatMap(([drone, points]) => points.map((p, n) => ({ drone, n, p })));
    for (const { drone, n, p } of all) {
      if (this.fence.length >= 3 && !inside(this.fence, p)) found.push({ drone, n, text: `${drone} waypoint ${n + 1} is outside the geofence` });
    }
    for (let a = 0; a < all.length; a++) {
      for (let b = a + 1; b < all.length; b++) {
        const [x, y] = [all[a], all[b]];
        if (x.drone === y.drone) continue;
        const apart = Math.hypot(metres(x.p, y.p), x.p.alt - y.p.alt);
        if (apart < this.separation) {
          found.push({ drone: y.drone, n: y.n, text: `targets conflict: ${x.drone} waypoint ${x.n + 1} and ${y.drone} waypoint ${y.n + 1} are ${apart.toFixed(1)} m apart (at least ${this.separation} m)` });
        }
      }
    }
    return found;
  }

  problemAt(drone, n) {
    return this.problems.some((p) => p.drone === drone && p.n === n);
  }

  scheduleCheck() {
    clearTimeout(this.checkTimer);
    this.checkTimer = setTimeout(() => this.check(), CHECK_MS);
  }

  async check() {
    const source = $("plan-script").value;
    const mine = ++this.checks;
    const local = this.localProblems();
    const r = source.trim() ? await call("POST", "/mission/check", { text: source }) : { ok: true, data: { problems: [] } };
    if (mine !== this.checks) return null; // a newer check is under way
    const remote = r.ok ? r.data.problems.map((p) => ({ text: `line ${p.line}, column ${p.column}: ${p.kind} error: ${p.message}` }))
      : [{ text: r.message }];
    this.problems = [...local, ...remote];
    const box = $("plan-problems");
    box.replaceChildren(...this.problems.map((p) => Object.assign(document.createElement("li"), { textContent: p.text })));
    box.hidden = !this.problems.length;
    $("plan-status").textContent = source.trim() ? (this.problems.length ? "the plan has problems" : "plan ok") : "";
    this.hooks.redraw();
    return this.problems;
  }

  async ready() {
    clearTimeout(this.checkTimer);
    const problems = await this.check();
    return problems !== null && !problems.length;
  }

  // ---- simulate, submit, save, load ---------------------------------------------------------

  async simulate() {
    if (!(await this.ready())) return;
    $("plan-status").textContent = "simulating on the ground…";
    $("plan-simulate").disabled = true;
    const r = await call("POST", "/mission/simulate", { json: { source: $("plan-script").value } });
    $("plan-simulate").disabled = false;
    if (!r.ok) {
      $("plan-status").textContent = r.message;
      return;
    }
    this.prediction = r.data;
    $("plan-status").textContent = `predicted: ${r.data.status}${r.data.cause ? ` (${r.data.cause})` : ""} in ${r.data.duration_s.toFixed(0)} s`
      + (r.data.message && r.data.status !== "finished" ? ` — ${r.data.message}` : "");
    this.renderPrediction();
    this.hooks.redraw();
  }

  renderPrediction() {
    const p = this.prediction;
    const rows = Object.entries(p?.drones || {}).map(([drone, d]) => {
      const tr = document.createElement("tr");
      tr.dataset.drone = drone;
      const left = d.battery_end == null ? "—" : `${Math.round(d.battery_end * 100)} %`;
      tr.innerHTML = `<td>${drone}</td><td>${d.flying_s.toFixed(0)} s flying</td><td class="battery-left">${left} battery left</td>`;
      return tr;
    });
    $("plan-result").replaceChildren(...rows);
    drawChart($("plan-chart"), p, [...this.plans.keys()]);
  }

  async submit() {
    if (!(await this.ready())) return;
    const r = await call("POST", "/mission", { text: $("plan-script").value });
    const pre = r.ok && r.data.preflight ? ` (preflight passed: ${r.data.preflight.t_s} s simulated)` : "";
    $("plan-status").textContent = r.ok ? `submitted as mission ${r.data.mission_id}${pre}` : r.message;
    if (r.ok) this.submitted = r.data.mission_id;
  }

  async exportPlan() {
    if (this.plans.size !== 1) {
      $("plan-status").textContent = "a .plan holds one drone's waypoints: plan one drone to export";
      return;
    }
    const [drone, points] = [...this.plans][0];
    const home = this.fleet.drones.get(drone)?.telem?.home || this.fleet.drones.get(drone)?.telem?.position;
    const r = await call("POST", "/mission/plan/export", { json: {
      waypoints: points, home: home ? [home.lat, home.lon, home.alt] : [points[0].lat, points[0].lon, 0],
      takeoff_alt: Number($("plan-takeoff").value || 10), end: $("plan-end").value,
    } });
    if (!r.ok) {
      $("plan-status").textContent = r.message;
      return;
    }
    this.exported = JSON.stringify(r.data, null, 2);
    download(`${drone}.plan`, this.exported, "application/json");
    $("plan-status").textContent = `exported ${points.length} waypoints of ${drone} as ${drone}.plan`;
  }

  /** A `.plan` (QGroundControl) into waypoints of the chosen drone, or a script as it is. */
  async load(file) {
    const text = await file.text();
    if (!file.name.toLowerCase().endsWith(".plan")) {
      this.plans.clear();
      this.changed();
      $("plan-script").value = text;
      this.scheduleCheck();
      return;
    }
    const drone = $("plan-drone").value;
    const r = await call("POST", `/mission/plan?drone=${encodeURIComponent(drone)}`, { text });
    if (!r.ok) {
      $("plan-status").textContent = r.message;
      return;
    }
    this.plans.clear();
    if (r.data.waypoints.length) this.plans.set(drone, r.data.waypoints.map((w) => ({ ...w, speed: w.speed ?? 5 })));
    if (r.data.takeoff_alt) $("plan-takeoff").value = r.data.takeoff_alt;
    $("plan-end").value = r.data.end;
    this.changed();
    $("plan-status").textContent = `imported ${r.data.waypoints.length} waypoints from ${file.name}`
      + (r.data.left_out.length ? `; not carried over: ${r.data.left_out.join("; ")}` : "");
  }
}

function strokePath(ctx, points) {
  if (points.length < 2) return;
  ctx.beginPath();
  ctx.moveTo(...points[0]);
  for (const p of points.slice(1)) ctx.lineTo(...p);
  ctx.stroke();
}

function drawChart(canvas, prediction, order) {
  const ctx = canvas.getContext("2d");
  const { width: w, height: h } = canvas;
  ctx.clearRect(0, 0, w, h);
  canvas.hidden = !prediction;
  if (!prediction) return;
  const end = Math.max(1, prediction.duration_s);
  ctx.strokeStyle = "#adb5bd";
  ctx.strokeRect(30, 5, w - 35, h - 20);
  ctx.fillStyle = "#495057";
  ctx.font = "10px sans-serif";
  ctx.fillText("100%", 2, 12);
  ctx.fillText("0", 18, h - 15);
  ctx.fillText(`${end.toFixed(0)} s`, w - 30, h - 3);
  for (const [drone, d] of Object.entries(prediction.drones)) {
    ctx.strokeStyle = COLOURS[Math.max(0, order.indexOf(drone)) % COLOURS.length];
    strokePath(ctx, d.battery.map(([t, b]) => [30 + (w - 35) * Math.min(1, t / end), 5 + (h - 20) * (1 - b)]));
  }
}

function download(name, text, type) {
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([text], { type }));
  a.download = name;
  a.click();
  setTimeout(() => URL.revokeObjectURL(a.href), 1000);
}

function fmt(x) {
  return String(Math.round(Number(x) * 100) / 100);
}

function metres(a, b) {
  const dLat = (b.lat - a.lat) * Math.PI / 180;
  const dLon = (b.lon - a.lon) * Math.PI / 180 * Math.cos((a.lat + b.lat) * Math.PI / 360);
  return R * Math.hypot(dLat, dLon);
}

function inside(polygon, p) {
  let odd = false;
  for (let i = 0, j = polygon.length - 1; i < polygon.length; j = i++) {
    const [a, b] = [polygon[i], polygon[j]];
    if ((a.lat > p.lat) !== (b.lat > p.lat) && p.lon < (b.lon - a.lon) * (p.lat - a.lat) / (b.lat - a.lat) + a.lon) odd = !odd;
  }
  return odd;
}
