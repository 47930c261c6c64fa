// One cyclic subscription and its event stream: the only live connection a data item view holds.
//
//   open()         POST {entity}/cyclic-subscriptions, then an EventSource on its event_source
//   setInterval()  PUT {interval}: the open stream is retimed, no reconnect
//   close()        DELETE (the gateway ends the stream at once), then the EventSource is closed
//
// The subscription is renewed (PUT {duration}) well before it expires.  When the stream ends
// unexpectedly (the gateway restarted, the subscription expired while the machine slept) the
// EventSource is closed at once, before it could retry on its own against a subscription that
// may be gone, and this class finds its subscription again or makes a new one, with backoff.
// While the ROS worker restarts the stream stays open and carries error frames: those go to
// onFrame like data frames.

import { eventSource, get, request } from "./api.js";

const DURATION_S = 120;           // asked per subscription, renewed at half-time: a page that dies leaves it for 2 min at most
const RETRY_MIN_MS = 500;
const RETRY_MAX_MS = 10000;
const CLOSE_WAIT_MS = 2000;       // how long close() waits for the gateway to end the stream

export class Subscription {
  /**
   * @param {string} entityHref   the entity's API path ("/api/v1/apps/x")
   * @param {string} resource     the data item's API path, with its query ("/api/v1/apps/x/data/a/b?bytes=base64")
   * @param {object} handlers     onFrame(frame), onState(state, detail): "connecting" | "live" | "retrying" | "closed"
   */
  constructor(entityHref, resource, interval, { onFrame, onState }) {
    this.entityHref = entityHref;
    this.resource = resource;
    this.interval = interval;
    this.onFrame = onFrame;
    this.onState = onState;
    this.sub = null;
    this.source = null;
    this.closed = false;
    this.retryMs = RETRY_MIN_MS;
    this.timers = new Set();
  }

  get collectionPath() {
    return `${this.entityHref}/cyclic-subscriptions`;
  }

  get subPath() {
    return `${this.collectionPath}/${this.sub.id}`;
  }

  async open() {
    this.onState("connecting");
    try {
      this.sub = await request("POST", this.collectionPath, {
        body: { resource: this.resource, interval: this.interval, duration: DURATION_S },
      });
    } catch (error) {
      this._retry(error);
      return;
    }
    if (this.closed) {
      this._delete();
      return;
    }
    this._listen();
  }

  _listen() {
    const source = eventSource(this.sub.event_source);
    this.source = source;
    source.onopen = () => {
      this.retryMs = RETRY_MIN_MS;
      this.onState("live");
    };
    source.onmessage = (event) => {
      let frame;
      try {
        frame = JSON.parse(event.data);
      } catch {
        return; // not a frame of this gateway
      }
      this.onFrame(frame);
    };
    source.onerror = () => {
      // The stream ended or could not be opened.  Never let the EventSource retry by itself.
      source.close();
      if (this.source !== source) return;
      this.source = null;
      if (this.closing) {
        this.closing();
        return;
      }
      if (!this.closed) this._retry(new Error("the event stream ended"));
    };
    this._renewIn((DURATION_S * 1000) / 2);
  }

  _renewIn(ms) {
    clearTimeout(this.renewTimer);
    this.timers.delete(this.renewTimer);
    this.renewTimer = this._schedule(() => this._renew(), ms);
  }

  async _renew() {
    if (this.closed || !this.sub) return;
    try {
      this.sub = await request("PUT", this.subPath, { body: { duration: DURATION_S } });
      this._renewIn((DURATION_S * 1000) / 2);
    } catch {
      // The stream ends at expiry at the latest; _retry then finds or remakes the subscription.
      this._renewIn(RETRY_MAX_MS);
    }
  }

  _retry(error) {
    if (this.closed) return;
    this.onState("retrying", error);
    const wait = this.retryMs;
    this.retryMs = Math.min(this.retryMs * 2, RETRY_MAX_MS);
    this._schedule(() => this._recover(), wait);
  }

  async _recover() {
    if (this.closed) return;
    if (this.sub) {
      // Still there?  The listing answers 200 either way (a GET of a gone one would be a 404).
      try {
        const listing = await get(this.collectionPath);
        if (this.closed) return;
        const mine = (listing.items || []).find((s) => s.id === this.sub.id);
        if (mine) {
          this.sub = mine;
          this.onState("connecting");
          this._listen();
          return;
        }
        this.sub = null;
      } catch (error) {
        this._retry(error);
        return;
      }
    }
    await this.open();
  }

  /** Retime the open stream (fast / normal / slow). */
  async setInterval(interval) {
    this.interval = interval;
    if (!this.sub || this.closed) return;
    this.sub = await request("PUT", this.subPath, { body: { interval } });
  }

  /**
   * DELETE the subscription and end the stream.  Resolves once the stream has ended (or after
   * CLOSE_WAIT_MS).  With `unloading` (the page goes away) the DELETE is sent as a keepalive
   * request and nothing is awaited.
   */
  close({ unloading = false } = {}) {
    if (this.closed) return Promise.resolve();
    this.closed = true;
    for (const timer of this.timers) clearTimeout(timer);
    this.timers.clear();
    this.onState("closed");
    if (!this.sub) return Promise.resolve();
    const source = this.source;
    if (unloading || !source) {
      if (source) source.close();
      return this._delete(unloading);
    }
    this._delete();
    // The gateway ends the stream when the DELETE is done: wait for that end rather than abort
    // the request from this side.
    return new Promise((resolve) => {
      const done = () => {
        clearTimeout(timer);
        source.close();
        this.source = null;
        resolve();
      };
      const timer = setTimeout(done, CLOSE_WAIT_MS);
      this.closing = done;
    });
  }

  _delete(keepalive = false) {
    return request("DELETE", this.subPath, { keepalive }).catch(() => {});
  }

  _schedule(fn, ms) {
    const timer = setTimeout(() => {
      this.timers.delete(timer);
      fn();
    }, ms);
    this.timers.add(timer);
    return timer;
  }
}
