// The gateway's API, reached by relative URLs only.
//
// The page lives at <prefix>/ui/ and the API at <prefix>/api/v1/, so the API base is computed
// from where the page was loaded: the dashboard works unchanged behind a proxy that mounts the
// gateway under a path prefix.  The API itself answers absolute paths ("/api/v1/apps/x", the
// "event_source" of a subscription): `url()` rewrites them onto the base.  Paths are kept in
// the API's own form everywhere else (a subscription's "resource" must be written that way).

export const API_PREFIX = "/api/v1/";
export const API_BASE = new URL("../api/v1/", document.baseURI);
const REQUEST_TIMEOUT_MS = 10000;

// The bearer token, when the gateway wants one (GET /api/v1/ says so: capabilities.authentication).
// It is kept in this module's memory only, for the life of the page: never in storage, never in a
// URL.  Every request but a read carries it: the gateway asks it for publishing and for making,
// changing and deleting cyclic subscriptions.  setToken() tells the page ("sovd-token").
let token = "";

// Through the fleet gateway every read needs the token too (fleet.js turns this on).
let readsNeedToken = false;

export function setReadsNeedToken(value) {
  readsNeedToken = Boolean(value);
}

export function getToken() {
  return token;
}

export function setToken(value) {
  if (value === token) return;
  token = value;
  window.dispatchEvent(new CustomEvent("sovd-token", { detail: { token } }));
}

/** The fetchable URL of an API path ("/api/v1/apps/x" or "apps/x"). */
export function url(path) {
  if (path.startsWith(API_PREFIX)) path = path.slice(API_PREFIX.length);
  else if (path.startsWith("/")) throw new Error(`not an API path: ${path}`);
  return new URL(path, API_BASE);
}

/** An error answer of the gateway: its status and its JSON error body (error_code, message, parameters). */
export class ApiError extends Error {
  constructor(status, body) {
    super(body && typeof body.message === "string" ? body.message : `HTTP ${status}`);
    this.status = status;
    this.body = body || {};
  }
}

/**
 * One request; resolves to the parsed JSON body (null for 204), rejects with ApiError for an
 * error answer, or with the fetch's own error when the gateway cannot be reached in time.
 */
export async function request(method, path, { body, headers = {}, timeout = REQUEST_TIMEOUT_MS,
                                              keepalive = false } = {}) {
  const init = { method, headers: { Accept: "application/json", ...headers }, keepalive,
                 signal: AbortSignal.timeout(timeout) };
  if (token && (method !== "GET" || readsNeedToken) && !init.headers.Authorization) init.headers.Authorization = `Bearer ${token}`;
  if (body !== undefined) {
    init.body = JSON.stringify(body);
    init.headers["Content-Type"] = "application/json";
  }
  const response = await fetch(url(path), init);
  if (response.status === 204) return null;
  const text = await response.text();
  let parsed = null;
  try {
    parsed = text ? JSON.parse(text) : null;
  } catch {
    parsed = { message: text.slice(0, 200) };
  }
  if (!response.ok) throw new ApiError(response.status, parsed);
  return parsed;
}

export const get = (path, options) => request("GET", path, options);

/** A short text for any error a request may reject with. */
export function describe(error) {
  if (error instanceof ApiError) {
    const code = error.body.vendor_code || error.body.error_code || "";
    return `${error.status} ${error.message}${code ? ` (${code})` : ""}`;
  }
  if (error && error.name === "TimeoutError") return "no answer from the gateway in time";
  return `the gateway cannot be reached (${error && error.message ? error.message : error})`;
}
