// The map: drones (state colour, heading, battery, track), the fence, heat sources,
// field sensors (magenta diamonds with their latest readings) and the ground station
// on a canvas, over raster tiles (`dashboard.tiles`) or a
// local metres grid with a scale bar. Drag pans, the wheel and the buttons zoom; a
// click selects a drone, or, while picking a goto target, answers with its lat/lon.

import { niceMetres } from "./view.js";

export const STATE_COLOURS = {
  ready: "#2e9d4f", active: "#2f6fd6", hold: "#0e9aa7", manual: "#8a4fd6", unreachable: "#d98a1a", error: "#d13434", unknown: "#8a8f98",
};
export const FIELD_SENSOR_COLOUR = "#d61fd6";
const LABELS_UP_TO = 40; // more drones than this: only the selected one is labelled
const HIT_PX = 16;
const DRAG_PX = 4;
const TILE_CACHE = 400;
const TRACK_PX = 2; // a track keeps a point per this many pixels of movement on screen
const TILE_MAX_Z = 19; // what tile servers usually have (an archive says its own); closer, the deepest tiles are scaled up
const FIT_MAX_Z = 18; // the first view (and every fit) is no closer: tile servers holding only 15-18 still draw it
const ANCESTORS = 5; // a missing tile is drawn from its parent, or that one's, … this many levels up
const MIN_FIT_M = 80;

export class MapView {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {import("./view.js").View} view
   * @param {import("./store.js").Fleet} fleet
   * @param {object} config GET /dashboard/config.json
   * @param {{redraw: function(): void, select: function(string): void, followOff: function(): void}} hooks
   */
  constructor(canvas, view, fleet, config, hooks) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d", { alpha: false });
    this.view = view;
    this.fleet = fleet;
    this.config = config;
    this.hooks = hooks;
    this.selected = null;
    this.follow = false;
    this.autoFit = true; // until the user pans or zooms
    this.pick = null; // function(lat, lon) while picking a goto target
    this.overlay = null; // the planner: draw(ctx, view), grab(sx, sy) → drag(lat, lon) | null, click(lat, lon) → bool
    this.tiles = new Map();
    this.drawn = -1;
    this.scaleLabel = document.getElementById("scale-label");
    this.scaleBar = document.getElementById("scale-bar");
    this.tileMaxZ = config.tiles_max_zoom ?? TILE_MAX_Z;
    const credit = document.getElementById("attribution");
    credit.textContent = config.tiles ? config.attribution || "" : "";
    credit.hidden = !credit.textContent;
    this.fence = (config.geofence.polygon || []).map(([lat, lon]) => ({ lat, lon }));
    const first = this.fence[0] || config.ground_station;
    if (first) view.ensureOrigin(first.lat, first.lon);
    this._listen();
  }

  resize() {
    const rect = this.canvas.getBoundingClientRect();
    const dpr = Math.min(window.devicePixelRatio || 1, 2);
    this.view.width = Math.max(rect.width, 1);
    this.view.height = Math.max(rect.height, 1);
    this.canvas.width = Math.round(this.view.width * dpr);
    this.canvas.height = Math.round(this.view.height * dpr);
    this.dpr = dpr;
  }

  /** Screen position (CSS px in the canvas) of a drone, or null. */
  screenOf(id) {
    const p = this.fleet.drones.get(id)?.telem?.position;
    return p && this.view.origin ? this.view.toScreen(p.lat, p.lon) : null;
  }

  toScreen(lat, lon) {
    return this.view.toScreen(lat, lon);
  }

  fitAll() {
    const v = this.view;
    const points = this.fence.length ? this.fence : [];
    if (!points.length) {
      for (const d of this.fleet.drones.values()) if (d.telem?.position) points.push(d.telem.position);
      for (const f of this.fleet.fieldSensors.values()) if (points.length) points.push(f.position);
      const gs = this.groundStation();
      if (gs && points.length) points.push(gs);
    }
    if (!points.length || !v.origin) return false;
    let [x0, y0, x1, y1] = [Infinity, Infinity, -Infinity, -Infinity];
    for (const p of points) {
      const [x, y] = v.project(p.lat, p.lon);
      x0 = Math.min(x0, x); y0 = Math.min(y0, y); x1 = Math.max(x1, x); y1 = Math.max(y1, y);
    }
    // Never closer than MIN_FIT_M across: one drone alone is not a whole screen.
    const minSpan = MIN_FIT_M * v.unitsPerMetre(v.unproject((x0 + x1) / 2, (y0 + y1) / 2)[0]);
    const grow = (a, b) => (b - a < minSpan ? [(a + b) / 2 - minSpan / 2, (a + b) / 2 + minSpan / 2] : [a, b]);
    [x0, x1] = grow(x0, x1);
    [y0, y1] = grow(y0, y1);
    v.fit([x0, y0, x1, y1]);
    if (v.mode === "mercator") v.zoom = Math.min(v.zoom, FIT_MAX_Z);
    return true;
  }

  groundStation() {
    return this.config.ground_station || this.fleet.firstHome();
  }

  // ---- drawing ----------------------------------------------------------------------

  draw() {
    const { ctx, view: v, fleet } = this;
    if (this.autoFit && (fleet.membershipChanged || !this.fitted)) this.fitted = this.fitAll() || this.fitted;
    if (this.follow && this.selected) {
      const p = fleet.drones.get(this.selected)?.telem?.position;
      if (p && v.origin) v.center = v.project(p.lat, p.lon);
    }
    ctx.setTransform(this.dpr, 0, 0, this.dpr, 0, 0);
    ctx.fillStyle = "#e9ecef";
    ctx.fillRect(0, 0, v.width, v.height);
    if (!v.origin) {
      this._setDrawn(0);
      return;
    }
    this._drawGrid(); // under the tiles too: where none is drawn, the map is never blank
    if (v.mode === "mercator") this._drawTiles();
    this._drawScale();
    this._drawFence();
    this._drawHeat();
    this._drawGround();
    this._drawFieldSensors();
    const drones = fleet.sortedIds().map((id) => fleet.drones.get(id));
    this._drawTracks(drones);
    this._drawTarget();
    this.overlay?.draw(ctx, v);
    this._setDrawn(this._drawDrones(drones));
  }

  _setDrawn(count) {
    if (count !== this.drawn) {
      this.drawn = count;
      this.canvas.dataset.drones = String(count);
    }
  }

  _drawGrid() {
    const { ctx, view: v } = this;
    // plane units per metre: 1 on the local grid; on mercator the scale at the centre
    const perMetre = v.mode === "mercator" ? 1 / (v.metresPerPixel() * v.scale) : 1;
    const step = niceMetres(v.metresPerPixel() * 90) * perMetre;
    const [x0, y0] = v.screenToPlane(0, 0);
    const [x1, y1] = v.screenToPlane(v.width, v.height);
    ctx.lineWidth = 1;
    for (const [major, colour] of [[false, "#dadee3"], [true, "#c3c8cf"]]) {
      const s = major ? step * 5 : step;
      ctx.strokeStyle = colour;
      ctx.beginPath();
      for (let x = Math.ceil(x0 / s) * s; x <= x1; x += s) {
        const sx = Math.round(v.planeToScreen(x, 0)[0]) + 0.5;
        ctx.moveTo(sx, 0); ctx.lineTo(sx, v.height);
      }
      for (let y = Math.ceil(y0 / s) * s; y <= y1; y += s) {
        const sy = Math.round(v.planeToScreen(0, y)[1]) + 0.5;
        ctx.moveTo(0, sy); ctx.lineTo(v.width, sy);
      }
      ctx.stroke();
    }
  }

  _drawTiles() {
    const { ctx, view: v } = this;
    const z = Math.max(0, Math.min(this.tileMaxZ, Math.round(v.zoom)));
    const n = 2 ** z;
    const [x0, y0] = v.screenToPlane(0, 0);
    const [x1, y1] = v.screenToPlane(v.width, v.height);
    const size = v.scale / n;
    let drawn = 0;
    for (let ty = Math.max(0, Math.floor(y0 * n)); ty <= Math.min(n - 1, Math.floor(y1 * n)); ty++) {
      for (let tx = Math.floor(x0 * n); tx <= Math.floor(x1 * n); tx++) {
        const [sx, sy] = v.planeToScreen(tx / n, ty / n);
        const found = this._tileOrAncestor(z, ((tx % n) + n) % n, ty);
        if (!found) continue;
        const { img, up, dx, dy } = found;
        const part = img.naturalWidth / 2 ** up; // the part of an ancestor that covers this tile
        ctx.drawImage(img, dx * part, dy * part, part, part, Math.floor(sx), Math.floor(sy), Math.ceil(size) + 1, Math.ceil(size) + 1);
        drawn++;
      }
    }
    this.canvas.dataset.tiles = String(drawn);
  }

  /** The tile at z/x/y once loaded; while it loads or where the server has none, the
   *  nearest loaded ancestor (`up` levels up, this tile at `dx`, `dy` inside it). A
   *  missing tile asks for its parent, so a server that stops at a lower zoom still
   *  draws, scaled up. */
  _tileOrAncestor(z, x, y) {
    let ask = true; // a level is asked for only once every level below it failed
    for (let up = 0; up <= Math.min(ANCESTORS, z); up++) {
      const [pz, px, py] = [z - up, x >> up, y >> up];
      const entry = ask ? this._tile(pz, px, py) : this.tiles.get(`${pz}/${px}/${py}`);
      if (entry?.ready) return { img: entry.img, up, dx: x - (px << up), dy: y - (py << up) };
      ask = ask && entry !== undefined && entry.failed;
    }
    return null;
  }

  _tile(z, x, y) {
    const key = `${z}/${x}/${y}`;
    let entry = this.tiles.get(key);
    if (!entry) {
      const img = new Image();
      entry = { img, ready: false, failed: false };
      img.onload = () => { entry.ready = true; this.hooks.redraw(); };
      img.onerror = () => { entry.failed = true; this.hooks.redraw(); };
      img.src = this.config.tiles.replace("{z}", z).replace("{x}", x).replace("{y}", y);
      this.tiles.set(key, entry);
      if (this.tiles.size > TILE_CACHE) this.tiles.delete(this.tiles.keys().next().value);
    }
    return entry;
  }

  _drawScale() {
    const mpp = this.view.metresPerPixel();
    const metres = niceMetres(mpp * 120);
    const width = `${Math.round(metres / mpp)}px`;
    const label = metres >= 1000 ? `${metres / 1000} km` : `${metres} m`;
    if (this.scaleBar.style.width !== width) this.scaleBar.style.width = width;
    if (this.scaleLabel.textContent !== label) this.scaleLabel.textContent = label;
  }

  _drawFence() {
    if (this.fence.length < 3) return;
    const { ctx, view: v } = this;
    ctx.beginPath();
    for (const p of this.fence) ctx.lineTo(...v.toScreen(p.lat, p.lon));
    ctx.closePath();
    ctx.fillStyle = "rgba(209, 52, 52, 0.04)";
    ctx.fill();
    ctx.setLineDash([8, 5]);
    ctx.strokeStyle = "#d13434";
    ctx.lineWidth = 2;
    ctx.stroke();
    ctx.setLineDash([]);
  }

  _drawHeat() {
    const { ctx, view: v } = this;
    const mpp = v.metresPerPixel();
    for (const h of this.config.heat_sources || []) {
      const [x, y] = v.toScreen(h.lat, h.lon);
      const r = h.radius / mpp;
      const g = ctx.createRadialGradient(x, y, 0, x, y, r);
      g.addColorStop(0, "rgba(235, 80, 20, 0.55)");
      g.addColorStop(1, "rgba(235, 160, 20, 0)");
      ctx.fillStyle = g;
      ctx.beginPath();
      ctx.arc(x, y, r, 0, 2 * Math.PI);
      ctx.fill();
    }
  }

  /** Field sensors (SPEC §2): a magenta diamond each, its id and latest readings beside;
   * one whose liveliness token went is drawn hollow. */
  _drawFieldSensors() {
    const { ctx, view: v, fleet } = this;
    let count = 0;
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "left";
    ctx.textBaseline = "middle";
    for (const f of fleet.fieldSensors.values()) {
      count++;
      const [x, y] = v.toScreen(f.position.lat, f.position.lon);
      ctx.beginPath();
      ctx.moveTo(x, y - 7); ctx.lineTo(x + 7, y); ctx.lineTo(x, y + 7); ctx.lineTo(x - 7, y);
      ctx.closePath();
      ctx.lineWidth = 2;
      ctx.strokeStyle = FIELD_SENSOR_COLOUR;
      ctx.fillStyle = f.alive === false ? "#ffffff" : FIELD_SENSOR_COLOUR;
      ctx.fill();
      ctx.stroke();
      ctx.fillStyle = "#1d2129";
      ctx.fillText(`${f.id} ${readingsText(f.readings)}`, x + 10, y);
    }
    if (this.canvas.dataset.fieldSensors !== String(count)) this.canvas.dataset.fieldSensors = String(count);
  }

  _drawGround() {
    const gs = this.groundStation();
    if (!gs) return;
    const { ctx, view: v } = this;
    const [x, y] = v.toScreen(gs.lat, gs.lon);
    ctx.fillStyle = "#1d2129";
    ctx.fillRect(x - 6, y - 6, 12, 12);
    ctx.fillStyle = "#fff";
    ctx.font = "bold 8px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.textBaseline = "middle";
    ctx.fillText("G", x, y + 0.5);
  }

  /** Every track, one path per colour (hundreds of strokes cost more than a few long
   * ones), thinned to a point per TRACK_PX on screen; thin lines rasterise fastest. */
  _drawTracks(drones) {
    const { ctx, view: v } = this;
    const k = v.scale;
    const cx = v.width / 2 - v.center[0] * k;
    const cy = v.height / 2 - v.center[1] * k;
    const paths = new Map();
    for (const d of drones) {
      const t = d.track;
      if (t.length < 4) continue;
      const colour = d.id === this.selected ? "selected" : colourOf(d);
      let path = paths.get(colour);
      if (!path) paths.set(colour, (path = new Path2D()));
      let x = cx + t[0] * k;
      let y = cy + t[1] * k;
      path.moveTo(x, y);
      for (let i = 2; i < t.length; i += 2) {
        const nx = cx + t[i] * k;
        const ny = cy + t[i + 1] * k;
        if (Math.abs(nx - x) + Math.abs(ny - y) < TRACK_PX && i < t.length - 2) continue;
        path.lineTo(nx, ny);
        x = nx;
        y = ny;
      }
      const p = d.telem?.position;
      if (p) path.lineTo(...v.toScreen(p.lat, p.lon));
    }
    for (const [colour, path] of paths) {
      const selected = colour === "selected";
      ctx.strokeStyle = selected ? "#1d2129aa" : colour + "88";
      ctx.lineWidth = selected ? 2 : 1;
      ctx.stroke(path);
    }
  }

  _drawTarget() {
    const d = this.selected && this.fleet.drones.get(this.selected);
    const c = d?.info?.current_command?.coords;
    const p = d?.telem?.position;
    if (!c || !p) return;
    const { ctx, view: v } = this;
    const [x, y] = v.toScreen(c.lat, c.lon);
    ctx.strokeStyle = "#2f6fd6";
    ctx.lineWidth = 1.5;
    ctx.setLineDash([4, 4]);
    ctx.beginPath();
    ctx.moveTo(...v.toScreen(p.lat, p.lon));
    ctx.lineTo(x, y);
    ctx.stroke();
    ctx.setLineDash([]);
    ctx.beginPath();
    ctx.arc(x, y, 7, 0, 2 * Math.PI);
    ctx.moveTo(x - 11, y); ctx.lineTo(x + 11, y);
    ctx.moveTo(x, y - 11); ctx.lineTo(x, y + 11);
    ctx.stroke();
  }

  /** Every drone: an arrow along its heading in its state's colour (one path per
   * colour), a battery bar under it, and a label when few enough to read. */
  _drawDrones(drones) {
    const { ctx, view: v } = this;
    const arrows = new Map();
    const outline = new Path2D();
    const bars = new Map();
    const barBacks = new Path2D();
    const labels = [];
    let count = 0;
    for (const d of drones) {
      const t = d.telem;
      const p = t?.position;
      if (!p) continue;
      count++;
      const [x, y] = v.toScreen(p.lat, p.lon);
      if (x < -50 || y < -50 || x > v.width + 50 || y > v.height + 50) continue;
      const colour = d.info?.state === "unknown" ? STATE_COLOURS.unknown + "80" : colourOf(d);
      let arrow = arrows.get(colour);
      if (!arrow) arrows.set(colour, (arrow = new Path2D()));
      const a = (t.heading || 0) * Math.PI / 180;
      const sin = Math.sin(a);
      const cos = Math.cos(a);
      const at = (px, py) => [x + px * cos - py * sin, y + px * sin + py * cos];
      for (const path of [arrow, outline]) {
        path.moveTo(...at(0, -10));
        path.lineTo(...at(7, 7));
        path.lineTo(...at(0, 3));
        path.lineTo(...at(-7, 7));
        path.closePath();
      }
      const battery = t.battery?.remaining_percent;
      if (battery != null) {
        barBacks.rect(x - 9, y + 11, 18, 4);
        const level = battery <= 0.15 ? "#d13434" : battery <= 0.3 ? "#d9a21b" : "#2e9d4f";
        let bar = bars.get(level);
        if (!bar) bars.set(level, (bar = new Path2D()));
        bar.rect(x - 8, y + 12, 16 * Math.max(0, Math.min(1, battery)), 2);
      }
      if (d.id === this.selected || drones.length <= LABELS_UP_TO) labels.push([d, x, y, battery]);
    }
    ctx.strokeStyle = "#fff";
    ctx.lineWidth = 1.2;
    ctx.stroke(outline);
    for (const [colour, path] of arrows) {
      ctx.fillStyle = colour;
      ctx.fill(path);
    }
    ctx.fillStyle = "#1d2129";
    ctx.fill(barBacks);
    for (const [level, path] of bars) {
      ctx.fillStyle = level;
      ctx.fill(path);
    }
    for (const [d, x, y, battery] of labels) this._label(d, x, y, battery);
    return count;
  }

  _label(d, x, y, battery) {
    const ctx = this.ctx;
    if (d.id === this.selected) {
      ctx.beginPath();
      ctx.arc(x, y, 14, 0, 2 * Math.PI);
      ctx.strokeStyle = "#1d2129";
      ctx.lineWidth = 2;
      ctx.stroke();
    }
    const numbers = `${battery != null ? `${Math.round(battery * 100)}% · ` : ""}${(d.telem.position.rel_alt ?? 0).toFixed(1)} m`;
    ctx.textAlign = "left";
    ctx.textBaseline = "middle";
    ctx.lineWidth = 3;
    ctx.strokeStyle = "rgba(255,255,255,0.85)";
    ctx.fillStyle = "#1d2129";
    for (const [text, dy, font] of [[d.id, -7, "600 11px system-ui, sans-serif"], [numbers, 6, "10px system-ui, sans-serif"]]) {
      ctx.font = font;
      ctx.strokeText(text, x + 12, y + dy);
      ctx.fillText(text, x + 12, y + dy);
    }
  }

  // ---- interaction --------------------------------------------------------------------

  startPick(callback) { this.pick = callback; this.canvas.classList.add("picking"); }

  stopPick() { this.pick = null; this.canvas.classList.remove("picking"); }

  hit(sx, sy) {
    let best = null;
    let bestD = HIT_PX;
    for (const d of this.fleet.drones.values()) {
      const p = d.telem?.position;
      if (!p) continue;
      const [x, y] = this.view.toScreen(p.lat, p.lon);
      const dist = Math.hypot(x - sx, y - sy);
      if (dist < bestD) { best = d.id; bestD = dist; }
    }
    return best;
  }

  zoom(steps, sx = this.view.width / 2, sy = this.view.height / 2) {
    if (!this.view.origin) return;
    this.autoFit = false;
    this.view.zoomAt(steps, sx, sy);
    this.hooks.redraw();
  }

  _listen() {
    const c = this.canvas;
    let down = null;
    c.addEventListener("pointerdown", (e) => {
      const grab = this.view.origin ? this.overlay?.grab(e.offsetX, e.offsetY) : null; // a waypoint to drag
      down = { x: e.offsetX, y: e.offsetY, lastX: e.offsetX, lastY: e.offsetY, dragging: false, grab };
      c.setPointerCapture(e.pointerId);
    });
    c.addEventListener("pointermove", (e) => {
      if (!down) return;
      if (!down.dragging && Math.hypot(e.offsetX - down.x, e.offsetY - down.y) > DRAG_PX) {
        down.dragging = true;
        this.autoFit = false;
        if (this.follow) this.hooks.followOff();
      }
      if (down.dragging && down.grab) down.grab(...this.view.toLatLon(e.offsetX, e.offsetY));
      else if (down.dragging && this.view.origin) this.view.panBy(e.offsetX - down.lastX, e.offsetY - down.lastY);
      if (down.dragging) this.hooks.redraw();
      down.lastX = e.offsetX;
      down.lastY = e.offsetY;
    });
    c.addEventListener("pointerup", (e) => {
      const was = down;
      down = null;
      if (!was || was.dragging || !this.view.origin) return;
      if (this.pick) {
        const [lat, lon] = this.view.toLatLon(e.offsetX, e.offsetY);
        const pick = this.pick;
        this.stopPick();
        pick(lat, lon);
      } else if (!this.overlay?.click(...this.view.toLatLon(e.offsetX, e.offsetY))) {
        const id = this.hit(e.offsetX, e.offsetY);
        if (id) this.hooks.select(id);
      }
    });
    c.addEventListener("pointercancel", () => { down = null; });
    c.addEventListener("wheel", (e) => {
      e.preventDefault();
      const steps = -e.deltaY / (e.deltaMode === 1 ? 6 : 240);
      this.zoom(Math.max(-1, Math.min(1, steps)), e.offsetX, e.offsetY);
    }, { passive: false });
  }
}

function colourOf(d) {
  return STATE_COLOURS[d.info?.state] || STATE_COLOURS.unknown;
}

/** A field sensor's latest readings in a line: "gas co_ppm 12.5 · temperature 21.3 degC". */
export function readingsText(readings) {
  return [...readings.values()].map((r) => {
    if (r.fields) return `${r.type} ${Object.entries(r.fields).map(([k, v]) => `${k} ${fmtValue(v)}`).join(" ")}`;
    return `${r.type} ${fmtValue(r.value)}${r.unit ? " " + r.unit : ""}`;
  }).join(" · ");
}

function fmtValue(v) {
  return typeof v === "number" ? String(Math.round(v * 10) / 10) : Array.isArray(v) ? `[${v.map(fmtValue).join(", ")}]` : String(v);
}
