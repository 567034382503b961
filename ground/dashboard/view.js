// What part of the world the map shows, and where a point lands on screen.
//
// Points are projected once into a "plane" (y pointing down) and drawn from it with
// one multiply-add: web mercator (normalised world 0..1) when the map draws raster
// tiles, or local metres east/south of a fixed origin for the plain grid. `zoom` is
// the slippy-map zoom level in both, so the scale at the centre is the same either way.

const EARTH_M = 6371000;
const DEG = Math.PI / 180;
const MERCATOR_M_PER_PX_Z0 = 156543.03392; // metres per pixel at the equator, zoom 0, 256 px tiles

export class View {
  constructor(mode) {
    this.mode = mode; // "mercator" | "local"
    this.origin = null; // [lat, lon] of the local plane
    this.center = [0, 0]; // plane coordinates of the screen centre
    this.zoom = 18;
    this.width = 1;
    this.height = 1;
  }

  /** Fix the local plane's origin (the first thing known); later calls do nothing. */
  ensureOrigin(lat, lon) {
    if (this.origin) return;
    this.origin = [lat, lon];
    this._cosLat = Math.cos(lat * DEG);
    this.center = this.project(lat, lon);
  }

  project(lat, lon) {
    if (this.mode === "mercator") {
      const s = Math.sin(Math.max(-85.05, Math.min(85.05, lat)) * DEG);
      return [(lon + 180) / 360, 0.5 - Math.log((1 + s) / (1 - s)) / (4 * Math.PI)];
    }
    const [lat0, lon0] = this.origin;
    return [(lon - lon0) * DEG * EARTH_M * this._cosLat, -(lat - lat0) * DEG * EARTH_M];
  }

  unproject(x, y) {
    if (this.mode === "mercator") {
      const lat = Math.atan(Math.sinh(Math.PI * (1 - 2 * y))) / DEG;
      return [lat, x * 360 - 180];
    }
    const [lat0, lon0] = this.origin;
    return [lat0 - y / (DEG * EARTH_M), lon0 + x / (DEG * EARTH_M * this._cosLat)];
  }

  /** Screen pixels per plane unit. */
  get scale() {
    const z = 2 ** this.zoom;
    return this.mode === "mercator" ? 256 * z : z / (MERCATOR_M_PER_PX_Z0 * this._cosLat);
  }

  /** Metres per screen pixel at the centre. */
  metresPerPixel() {
    if (this.mode !== "mercator") return 1 / this.scale;
    const [lat] = this.unproject(...this.center);
    return (MERCATOR_M_PER_PX_Z0 * Math.cos(lat * DEG)) / 2 ** this.zoom;
  }

  /** Plane units per metre on the ground at latitude `lat`. */
  unitsPerMetre(lat) {
    return this.mode === "mercator" ? 1 / (2 * Math.PI * EARTH_M * Math.cos(lat * DEG)) : 1;
  }

  planeToScreen(x, y) {
    const k = this.scale;
    return [this.width / 2 + (x - this.center[0]) * k, this.height / 2 + (y - this.center[1]) * k];
  }

  screenToPlane(sx, sy) {
    const k = this.scale;
    return [this.center[0] + (sx - this.width / 2) / k, this.center[1] + (sy - this.height / 2) / k];
  }

  toScreen(lat, lon) {
    return this.planeToScreen(...this.project(lat, lon));
  }

  toLatLon(sx, sy) {
    return this.unproject(...this.screenToPlane(sx, sy));
  }

  panBy(dx, dy) {
    const k = this.scale;
    this.center = [this.center[0] - dx / k, this.center[1] - dy / k];
  }

  /** Zoom by `steps` (1 = twice as close) keeping the point under (sx, sy) still. */
  zoomAt(steps, sx, sy) {
    const before = this.screenToPlane(sx, sy);
    this.zoom = Math.max(2, Math.min(22, this.zoom + steps));
    const after = this.screenToPlane(sx, sy);
    this.center = [this.center[0] + before[0] - after[0], this.center[1] + before[1] - after[1]];
  }

  /** Show the plane box [x0, y0, x1, y1] with `pad` pixels around it. */
  fit(box, pad = 40) {
    const [x0, y0, x1, y1] = box;
    this.center = [(x0 + x1) / 2, (y0 + y1) / 2];
    const spanPx = Math.max(this.width - 2 * pad, 50) / Math.max(x1 - x0, 1e-12);
    const spanPy = Math.max(this.height - 2 * pad, 50) / Math.max(y1 - y0, 1e-12);
    const k = Math.min(spanPx, spanPy);
    const base = this.mode === "mercator" ? 256 : 1 / (MERCATOR_M_PER_PX_Z0 * this._cosLat);
    this.zoom = Math.max(2, Math.min(20, Math.log2(k / base)));
  }
}

/** A round length (1, 2, 5 × 10^n metres) close to `maxMetres`. */
export function niceMetres(maxMetres) {
  const p = 10 ** Math.floor(Math.log10(maxMetres));
  for (const m of [5, 2, 1]) if (m * p <= maxMetres) return m * p;
  return p;
}
