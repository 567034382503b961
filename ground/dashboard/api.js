// The ground's HTTP API as the page uses it: every failure becomes a sentence a
// person can act on (status, the API's own reason, the field or line at fault).

// A ground with `api.tokens` (SPEC §9) answers 401 without one: the page asks for it
// once, keeps it in this browser (localStorage) and sends it with every request.
const TOKEN_KEY = "fleet-token";

export function token() {
  return window.localStorage.getItem(TOKEN_KEY) || "";
}

/** `url` with ?access_token= for an EventSource, which cannot send headers. */
export function withToken(url) {
  const t = token();
  return t ? `${url}${url.includes("?") ? "&" : "?"}access_token=${encodeURIComponent(t)}` : url;
}

function askToken() {
  const given = window.prompt("This ground needs an API token (api.tokens in its configuration):", "");
  if (given) window.localStorage.setItem(TOKEN_KEY, given.trim());
  return Boolean(given);
}

export async function call(method, path, options = {}, retried = false) {
  const response = await send(method, path, options);
  if (response.status === 401 && !retried && askToken()) return call(method, path, options, true);
  return response;
}

async function send(method, path, { json, text, timeoutMs } = {}) {
  const init = { method, headers: {} };
  // A request the ground never answers (a dropped connection on the field's Wi-Fi) ends
  // as a failure the caller can retry, not a page that waits forever.
  if (timeoutMs) init.signal = AbortSignal.timeout(timeoutMs);
  if (token()) init.headers.authorization = `Bearer ${token()}`;
  if (json !== undefined) {
    init.body = JSON.stringify(json);
    init.headers["content-type"] = "application/json";
  } else if (text !== undefined) {
    init.body = text;
    init.headers["content-type"] = "text/plain; charset=utf-8";
  }
  let response;
  try {
    response = await fetch(path, init);
  } catch (err) {
    return { ok: false, status: 0, data: null, message: `cannot reach the ground (${err.message}); is it running?` };
  }
  const type = response.headers.get("content-type") || "";
  const data = type.includes("json") ? await response.json().catch(() => null) : await response.text();
  if (response.ok) return { ok: true, status: response.status, data, message: "" };
  return { ok: false, status: response.status, data, message: describeFailure(response.status, data) };
}

const KINDS = {
  400: "invalid", 401: "unauthorized", 403: "forbidden", 404: "not found", 409: "refused", 413: "too large", 502: "agent error", 504: "no answer",
};

export function describeFailure(status, body) {
  const error = body && typeof body === "object" ? body.error : String(body || "").slice(0, 300);
  const detail = body && typeof body === "object" ? body.detail || {} : {};
  let text = `${status} ${KINDS[status] || "error"}: ${error || "(no reason given)"}`;
  if (detail.reason && !String(error).startsWith(detail.reason)) text += ` [${detail.reason}]`;
  if (detail.other) text += ` (other drone: ${detail.other})`;
  if (detail.field) text += ` (field ${detail.field})`;
  return text;
}
