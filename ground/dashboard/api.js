// The ground's HTTP API as the page uses it: every failure becomes a sentence a
// person can act on (status, the API's own reason, the field or line at fault).

export async function call(method, path, { json, text } = {}) {
  const init = { method, headers: {} };
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
  400: "invalid", 404: "not found", 409: "refused", 413: "too large", 502: "agent error", 504: "no answer",
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
