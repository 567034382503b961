// The ground's live events (GET /events, server-sent events), kept connected.
import { withToken } from "./api.js";
//
// EventSource retries on its own only for some failures, and gives up on others (an
// HTTP error while the ground restarts); so every error closes it and this opens a
// new one after a short, growing delay, until the ground answers again.

const KINDS = ["telemetry", "status", "drone", "log", "mission", "mission_log", "field_sensor", "subroutine"];
const RETRY_MS = [250, 500, 1000, 2000];

export class EventStream {
  /**
   * @param {string} url
   * @param {Object<string, function(object): void>} handlers one per event kind
   * @param {{onOpen: function(number): void, onDown: function(number): void}} hooks
   *   onOpen(connection number) once the stream is up; onDown(failed attempts) on each failure
   */
  constructor(url, handlers, hooks) {
    this.url = url;
    this.handlers = handlers;
    this.hooks = hooks;
    this.source = null;
    this.failures = 0;
    this.connections = 0;
    this.timer = null;
  }

  start() {
    clearTimeout(this.timer);
    const source = new EventSource(withToken(this.url));
    this.source = source;
    source.onopen = () => {
      this.failures = 0;
      this.connections++;
      this.hooks.onOpen(this.connections);
    };
    source.onerror = () => {
      if (this.source !== source) return;
      source.close();
      this.source = null;
      this.failures++;
      this.hooks.onDown(this.failures);
      this.timer = setTimeout(() => this.start(), RETRY_MS[Math.min(this.failures, RETRY_MS.length) - 1]);
    };
    for (const kind of KINDS) {
      const handle = this.handlers[kind];
      if (!handle) continue;
      source.addEventListener(kind, (event) => {
        let data;
        try {
          data = JSON.parse(event.data);
        } catch (err) {
          console.warn(`ignored a ${kind} event that is not JSON`, err);
          return;
        }
        handle(data);
      });
    }
  }
}
