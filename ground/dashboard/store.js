// What the page knows of the fleet, fed by the ground's events; no DOM here.
//
// Events only update this state and note what changed; the page redraws from it in
// batches (main.js), so a burst of telemetry costs one frame, not one per message.

import { MissionLanes } from "./lanes.js";

const TRACK_POINTS = 240; // per drone, thinned to one per ~0.3 m of movement
const TRACK_STEP_DEG = 3e-6;
const DRONE_LOG_LINES = 300;
const MISSION_LOG_LINES = 3000;

export class Fleet {
  constructor(view) {
    this.view = view;
    this.drones = new Map(); // id -> Drone
    this.missions = new Map(); // id -> record
    this.missionHeard = new Map(); // id -> when the stream last brought its record (performance.now())
    this.missionLogs = new Map(); // id -> [{timestamp, level, message}], the mission's own
    this.missionDroneLines = new Map(); // id -> its drones' lines heard while they were in it
    this.missionFetched = new Map(); // id -> keys of the last fetched lines, which the stream may bring again
    this.changed = new Set(); // drone ids whose row or details are stale
    this.membershipChanged = false; // drones came or went: the list is rebuilt
    this.missionsChanged = new Set();
    this.telemetryChanged = false; // the map has something new to draw
    this.epoch = 0; // bumped on each (re)connection of the event stream
    this.stats = { events: 0, telemetry: 0 };
    this.fieldSensors = new Map(); // id -> {id, position, alive, readings: Map type -> SensorReading}
    this.fieldSensorsChanged = false;
    this.lanes = new Map(); // mission id -> MissionLanes (lanes.js), for missions opened or heard running
  }

  /** A subroutine's activity from /events (SPEC §10 lanes). */
  onSubroutine(activity) {
    let lanes = this.lanes.get(activity.mission_id);
    if (!lanes) this.lanes.set(activity.mission_id, (lanes = new MissionLanes()));
    lanes.take(activity);
    this.missionsChanged.add(activity.mission_id);
  }

  /** A field sensor's reading from /events (SPEC §2 sensor/<id>/<type>). */
  onFieldSensor(reading) {
    const id = reading.sensor_id;
    if (!id || !reading.position) return;
    let s = this.fieldSensors.get(id);
    if (!s) this.fieldSensors.set(id, (s = { id, position: reading.position, alive: null, readings: new Map() }));
    s.position = reading.position;
    s.readings.set(reading.type, reading);
    this.fieldSensorsChanged = true;
  }

  /** GET /sensor: the field sensors the ground keeps now (those timed out are gone). */
  resyncFieldSensors(list) {
    this.fieldSensors = new Map(list.filter((s) => s.position).map((s) => [s.sensor_id, {
      id: s.sensor_id, position: s.position, alive: s.alive, readings: new Map(s.readings.map((r) => [r.type, r])),
    }]));
    this.fieldSensorsChanged = true;
  }

  drone(id) {
    let d = this.drones.get(id);
    if (!d) {
      d = { id, info: null, telem: null, track: [], last: null, log: [], heard: this.epoch, receivedAt: 0 };
      this.drones.set(id, d);
      this.membershipChanged = true;
    }
    d.heard = this.epoch;
    return d;
  }

  sortedIds() {
    return [...this.drones.keys()].sort();
  }

  onDrone(info) {
    const d = this.drone(info.drone_id);
    d.info = info;
    this.changed.add(d.id);
    this.telemetryChanged = true; // its colour on the map
  }

  onTelemetry(t) {
    this.stats.telemetry++;
    const d = this.drone(t.drone_id);
    d.telem = t;
    d.receivedAt = performance.now();
    const p = t.position;
    if (p) {
      this.view.ensureOrigin(p.lat, p.lon);
      if (!d.last || Math.abs(p.lat - d.last[0]) + Math.abs(p.lon - d.last[1]) > TRACK_STEP_DEG) {
        d.last = [p.lat, p.lon];
        d.track.push(...this.view.project(p.lat, p.lon));
        if (d.track.length > 4 * TRACK_POINTS) d.track.splice(0, d.track.length - 2 * TRACK_POINTS);
      }
    }
    this.changed.add(d.id);
    this.telemetryChanged = true;
  }

  onLog(line) {
    if (!line.drone_id) return;
    const d = this.drone(line.drone_id);
    if (d.fetched?.delete(line.text)) return; // already there: the fetch overtook the stream
    line.received = performance.now();
    d.log.push(line);
    if (d.log.length > 2 * DRONE_LOG_LINES) d.log.splice(0, d.log.length - DRONE_LOG_LINES);
    this.changed.add(d.id);
    const mission = d.info?.mission;
    if (mission) {
      // What a mission's drones do is part of its live log (its own lines are sparse).
      let lines = this.missionDroneLines.get(mission);
      if (!lines) this.missionDroneLines.set(mission, (lines = []));
      lines.push({ timestamp: line.timestamp, level: line.level, message: `${d.id}: ${line.message}`, drone: true });
      if (lines.length > MISSION_LOG_LINES) lines.splice(0, lines.length - MISSION_LOG_LINES);
      this.missionsChanged.add(mission);
    }
  }

  /** A mission's log as shown: its own lines and its drones' lines, in time order. */
  missionLog(id) {
    const own = this.missionLogs.get(id) || [];
    const drones = this.missionDroneLines.get(id) || [];
    if (!drones.length) return own;
    const merged = [];
    let i = 0;
    let j = 0;
    while (i < own.length || j < drones.length) {
      merged.push(j >= drones.length || (i < own.length && own[i].timestamp <= drones[j].timestamp) ? own[i++] : drones[j++]);
    }
    return merged;
  }

  /** Lines fetched from /drone/logs (text, asked for at `sentAt`) replace what the
   * stream brought before; what it brought since and the fetch missed stays after them. */
  setDroneLog(id, text, sentAt) {
    const d = this.drones.get(id);
    if (!d) return;
    const lines = text.split("\n").filter(Boolean).slice(-DRONE_LOG_LINES);
    const fetched = new Set(lines);
    const since = d.log.filter((l) => l.received >= sentAt && !fetched.has(l.text));
    d.log = [...lines.map((l) => ({ text: l, level: / (WARN|ERROR) /.exec(l)?.[1].toLowerCase() || "info" })), ...since];
    d.fetched = new Set(lines.slice(-50));
    this.changed.add(id);
  }

  /** A mission's record: from the stream (`sentAt` undefined), or from a request sent
   * at `sentAt` (performance.now()). A request's answer is older than any record the
   * stream brought after it was sent, and is dropped: arriving last, it turned a running
   * mission back to pending. */
  onMission(record, sentAt) {
    const heard = this.missionHeard.get(record.mission_id);
    if (sentAt !== undefined && heard !== undefined && heard >= sentAt) return;
    if (sentAt === undefined) this.missionHeard.set(record.mission_id, performance.now());
    this.missions.set(record.mission_id, record);
    this.missionsChanged.add(record.mission_id);
  }

  /** Start keeping a mission's lines from the stream (before fetching its log). */
  watchMission(id) {
    if (!this.missionLogs.has(id)) this.missionLogs.set(id, []);
  }

  /** A mission's own log as GET /mission/{id} (asked for at `sentAt`) has it, and what
   * the stream brought since that the fetch missed. */
  setMissionLog(id, lines, sentAt) {
    const fetched = new Set(lines.map(lineKey));
    const since = (this.missionLogs.get(id) || []).filter((l) => l.received >= sentAt && !fetched.has(lineKey(l)));
    this.missionLogs.set(id, [...lines, ...since]);
    this.missionFetched.set(id, new Set(lines.slice(-50).map(lineKey)));
    this.missionsChanged.add(id);
  }

  onMissionLog(line) {
    const lines = this.missionLogs.get(line.mission_id);
    if (!lines) return; // fetched in full when the mission is opened
    if (this.missionFetched.get(line.mission_id)?.delete(lineKey(line))) return; // the fetch overtook the stream
    line.received = performance.now();
    lines.push(line);
    if (lines.length > MISSION_LOG_LINES) lines.splice(0, lines.length - MISSION_LOG_LINES);
    this.missionsChanged.add(line.mission_id);
  }

  /** After the stream (re)connects: what GET /drone says now. A drone the ground no
   * longer knows (it restarted) goes until it is heard of again. */
  resync(views, epoch) {
    for (const v of views) {
      const id = (v.info || v.telem).drone_id;
      if (v.info) this.onDrone(v.info);
      const known = this.drones.get(id)?.telem;
      if (v.telem && (!known || v.telem.timestamp >= known.timestamp)) this.onTelemetry(v.telem);
    }
    for (const [id, d] of this.drones) {
      if (d.heard < epoch) {
        this.drones.delete(id);
        this.membershipChanged = true;
        this.telemetryChanged = true;
      }
    }
  }

  /** The first drone's home: where the ground station is assumed when not configured. */
  firstHome() {
    for (const id of this.sortedIds()) {
      const home = this.drones.get(id).telem?.home;
      if (home) return home;
    }
    return null;
  }
}

function lineKey(line) {
  return `${line.timestamp} ${line.level} ${line.message}`;
}
