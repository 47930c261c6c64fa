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

// The bearer token, when the gateway wants one (GET /api/v1/ says so: capabilities.authentication):
// the access token of a sign-in (signIn(): a gateway with identities and roles, GET /api/v1/'s
// auth), or the legacy token typed in the header.  It is kept in this module's memory only, for the
// life of the page: never in storage, never in a URL.  Every request but a read carries it, and a
// read too when reads need it (require_auth_for=all; through the fleet) or after a sign-in.  setToken() tells the page
// ("sovd-token"); a sign-in, a refresh and a sign-out tell it "sovd-auth".
let token = "";
let refreshToken = "";
let identity = null;      // after a sign-in: {client_id, role, may: {action: bool}, require_auth_for, ...}
let refreshTimer = null;
let identities = false;   // the gateway has identities and roles (auth_enabled)

// Through the fleet gateway, and under require_auth_for=all, every read needs the token too
// (fleet.js and main.js turn this on).
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

/** The gateway has identities and roles (GET /api/v1/'s auth): sign-in instead of a token field. */
export function setIdentities(value) {
  identities = Boolean(value);
}

export const identitiesOn = () => identities;
export const whoAmI = () => identity;

/**
 * May the signed-in client's role do this (an action of app/auth/roles.py's ACTIONS: "publish",
 * "operations", "configurations", "fault_clear", "cyclic_subscriptions", "triggers", "audit" ...)?
 * Without identities on the gateway: yes (its allow_* switches and the legacy token decide).
 */
export function may(action) {
  if (!identities) return true;
  return Boolean(identity && identity.may && identity.may[action]);
}

function announce() {
  window.dispatchEvent(new CustomEvent("sovd-auth", { detail: { identity } }));
}

/** OAuth2 client credentials: the tokens, then who they are (GET auth/x-medkit-whoami). */
export async function signIn(clientId, secret) {
  const granted = await request("POST", "auth/authorize", {
    body: { grant_type: "client_credentials", client_id: clientId, client_secret: secret } });
  await adopt(granted);
}

async function adopt(granted) {
  refreshToken = granted.refresh_token || refreshToken;
  setToken(granted.access_token);
  identity = await request("GET", "auth/x-medkit-whoami", { headers: { Authorization: `Bearer ${token}` } });
  clearTimeout(refreshTimer);
  // A new access token a minute before this one runs out (halfway through a short one).
  const inMs = Math.max(5, Math.min(granted.expires_in - 60, granted.expires_in / 2)) * 1000;
  refreshTimer = setTimeout(refresh, inMs);
  announce();
}

async function refresh() {
  try {
    await adopt(await request("POST", "auth/token", {
      body: { grant_type: "refresh_token", refresh_token: refreshToken } }));
  } catch {
    forget();   // revoked or expired: sign in again
  }
}

function forget() {
  clearTimeout(refreshTimer);
  refreshToken = "";
  identity = null;
  setToken("");
  announce();
}

/** Revoke the refresh token (and with it every access token made from it), then forget them. */
export async function signOut() {
  const revoked = refreshToken;
  forget();
  if (revoked) {
    try {
      await request("POST", "auth/revoke", { body: { token: revoked } });
    } catch { /* the tokens are gone from this page anyway */ }
  }
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
  if (token && (method !== "GET" || readsNeedToken || identities) && !init.headers.Authorization) {
    init.headers.Authorization = `Bearer ${token}`;   // a signed-in page's reads too (the audit trail wants it)
  }
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

/**
 * An event stream of an API path: the browser's EventSource, or, while reads need the token
 * (require_auth_for=all: an EventSource cannot send a header), the same over fetch with it.
 */
export function eventSource(path) {
  return readsNeedToken && token ? new TokenEventSource(url(path), token) : new EventSource(url(path));
}

/** What the page uses of EventSource (onopen, onmessage, onerror, addEventListener, close), over fetch. */
class TokenEventSource extends EventTarget {
  constructor(href, bearer) {
    super();
    this.href = href;
    this.bearer = bearer;
    this.onopen = null;
    this.onmessage = null;
    this.onerror = null;
    this.lastId = "";
    this.retryMs = 3000;
    this.readyState = 0;
    this.controller = null;
    this._connect();
  }

  _emit(type, event) {
    const handler = ["open", "message", "error"].includes(type) ? this[`on${type}`] : null;
    if (typeof handler === "function") handler.call(this, event);
    this.dispatchEvent(event);
  }

  async _connect() {
    this.controller = new AbortController();
    const headers = { Accept: "text/event-stream", Authorization: `Bearer ${this.bearer}` };
    if (this.lastId) headers["Last-Event-ID"] = this.lastId;
    try {
      const response = await fetch(this.href, { headers, signal: this.controller.signal });
      if (!response.ok || !response.body) throw new Error(`HTTP ${response.status}`);
      this.readyState = 1;
      this._emit("open", new Event("open"));
      const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
      let buffer = "";
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buffer += value;
        let match;
        while ((match = /\r?\n\r?\n/.exec(buffer))) {
          this._dispatch(buffer.slice(0, match.index));
          buffer = buffer.slice(match.index + match[0].length);
        }
      }
    } catch {
      // a refused or broken stream: as EventSource, an error, then a new try (unless closed)
    }
    if (this.readyState === 2) return;
    this.readyState = 0;
    this._emit("error", new Event("error"));
    if (this.readyState !== 2) this.timer = setTimeout(() => this._connect(), this.retryMs);
  }

  _dispatch(block) {
    let type = "message";
    const data = [];
    for (const line of block.split(/\r?\n/)) {
      if (!line || line.startsWith(":")) continue;
      const at = line.indexOf(":");
      const field = at < 0 ? line : line.slice(0, at);
      const text = at < 0 ? "" : line.slice(at + 1).replace(/^ /, "");
      if (field === "event") type = text;
      else if (field === "data") data.push(text);
      else if (field === "id") this.lastId = text;
      else if (field === "retry" && /^\d+$/.test(text)) this.retryMs = Number(text);
    }
    if (!data.length) return;
    this._emit(type, new MessageEvent(type, { data: data.join("\n"), lastEventId: this.lastId }));
  }

  close() {
    this.readyState = 2;
    clearTimeout(this.timer);
    if (this.controller) this.controller.abort();
  }
}
