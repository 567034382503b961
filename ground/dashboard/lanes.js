// A running mission, seen live (SPEC §10): each of its subroutines as a lane — its
// drone, the verb it is in with that line of the script highlighted, what it waits on —
// and its plugins' actions (relays sent, replacements) as marks on a timeline. Fed by
// `/events` `subroutine` and by GET /mission/{id} (`source`, `subroutines`, `marks`).

const $ = (id) => document.getElementById(id);
const MARKS = 500;

/** What the page knows of one mission's subroutines; no DOM here. */
export class MissionLanes {
  constructor() {
    this.subs = new Map(); // subroutine id → its latest activity (with `drones` kept from earlier verbs)
    this.marks = []; // plugin verbs, oldest first
    this.source = null; // the script's lines
  }

  take(a) {
    const before = this.subs.get(a.subroutine);
    const drones = a.drones?.length ? a.drones : before?.drones || [];
    this.subs.set(a.subroutine, { ...a, drones, started: before?.started ?? a.timestamp });
    if (a.plugin && a.event === "verb") {
      this.marks.push(a);
      if (this.marks.length > MARKS) this.marks.splice(0, this.marks.length - MARKS);
    }
  }

  /** GET /mission/{id}: the state when it was asked; events since then came on top. */
  seed(view) {
    if (view.source != null) this.source = view.source.split("\n");
    for (const a of view.subroutines || []) if (!this.subs.has(a.subroutine)) this.take(a);
    if (!this.marks.length) this.marks = [...(view.marks || [])];
  }
}

function doing(a) {
  if (a.event === "ended") return `ended: ${a.status}`;
  if (a.event === "started") return "started";
  if (a.event === "waiting") return `waiting on ${a.waiting_on}`;
  return a.verb;
}

/** Draws the selected mission's lanes, script and timeline into the missions tab. */
export function renderLanes(lanes, record) {
  const box = $("mission-lanes");
  box.hidden = !lanes || !lanes.subs.size;
  if (box.hidden) return;
  const rows = [...lanes.subs.values()].map((a) => {
    const row = document.createElement("div");
    row.className = `lane ${a.event}${a.plugin ? " plugin" : ""}`;
    Object.assign(row.dataset, { sub: a.subroutine, name: a.name, event: a.event, line: a.line ?? "", status: a.status || "" });
    const where = a.line != null && a.event !== "ended" ? `line ${a.line}` : "";
    const code = a.line != null && a.event !== "ended" ? (lanes.source?.[a.line - 1] || "").trim() : "";
    row.innerHTML = "<span class=\"lane-name\"></span><span class=\"lane-drone\"></span><span class=\"lane-doing\"></span>"
      + "<span class=\"lane-where\"></span><code class=\"lane-code\"></code>";
    const [name, drone, what, at, text] = row.children;
    name.textContent = a.plugin ? `${a.name} (plugin ${a.plugin})` : a.name;
    drone.textContent = a.drones.join(", ");
    what.textContent = doing(a);
    at.textContent = where;
    text.textContent = code;
    return row;
  });
  $("lane-rows").replaceChildren(...rows);
  renderScript(lanes);
  renderTimeline(lanes, record);
}

function renderScript(lanes) {
  const ol = $("mission-script");
  const lines = lanes.source || [];
  const at = new Map();
  for (const a of lanes.subs.values()) {
    if (a.line != null && a.event !== "ended") at.set(a.line, [...(at.get(a.line) || []), a.name]);
  }
  if (ol.children.length !== lines.length) {
    ol.replaceChildren(...lines.map((text) => Object.assign(document.createElement("li"), { textContent: text || " " })));
  }
  [...ol.children].forEach((li, i) => {
    const here = at.get(i + 1);
    li.classList.toggle("current", Boolean(here));
    li.title = here ? here.join(", ") : "";
  });
}

function renderTimeline(lanes, record) {
  const bar = $("mission-timeline");
  const start = record?.start ?? lanes.marks[0]?.timestamp ?? Date.now();
  const end = record?.end ?? Math.max(Date.now(), ...lanes.marks.map((m) => m.timestamp));
  const span = Math.max(1, end - start);
  bar.hidden = !lanes.marks.length;
  bar.replaceChildren(...lanes.marks.map((m) => {
    const mark = document.createElement("span");
    mark.className = "mark";
    mark.style.left = `${Math.min(100, Math.max(0, (100 * (m.timestamp - start)) / span))}%`;
    mark.title = `${new Date(m.timestamp).toLocaleTimeString()} plugin ${m.plugin}: ${m.verb} ${m.drones.join(", ")}`;
    mark.dataset.verb = m.verb;
    mark.dataset.plugin = m.plugin;
    return mark;
  }));
}
