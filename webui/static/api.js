// The service's HTTP API as the page uses it: operator sign-in, JSON requests, a session's event stream.

const TOKEN_KEY = "gyrocal.token";
const OPERATOR_KEY = "gyrocal.operator";
// every snapshot the service streams carries its kind as the SSE event name
const EVENT_NAMES = ["state", "prompt", "progress", "angle", "warning", "decision", "message"];

/** A failed request: HTTP status (0 when the service could not be reached) and the service's detail. */
export class ApiError extends Error {
  constructor(status, detail, path) {
    super(detail);
    this.status = status;
    this.detail = detail;
    this.path = path;
  }
  get network() {
    return this.status === 0;
  }
}

export class Api {
  constructor() {
    this.token = sessionStorage.getItem(TOKEN_KEY);
    this.operator = sessionStorage.getItem(OPERATOR_KEY);
    this.authReads = false;
    this.onUnauthorized = null; // set by the app: an expired token sends the operator to sign in
  }

  get signedIn() {
    return Boolean(this.token);
  }

  /** One request; the parsed JSON answer (or, with raw, {text, headers} of a successful one). */
  async request(method, path, { json, jsonText, csv, form, query, signingIn = false, raw = false } = {}) {
    const url = new URL(path, location.origin);
    for (const [k, v] of Object.entries(query || {})) if (v !== undefined && v !== null) url.searchParams.set(k, v);
    const headers = { Accept: "application/json" };
    if (this.token) headers.Authorization = `Bearer ${this.token}`;
    const init = { method, headers, cache: "no-store" };
    if (json !== undefined || jsonText !== undefined) {
      headers["Content-Type"] = "application/json";
      init.body = jsonText !== undefined ? jsonText : JSON.stringify(json); // jsonText: a file's own bytes, as they are
    } else if (csv !== undefined) {
      headers["Content-Type"] = "text/csv";
      init.body = csv;
    } else if (form !== undefined) {
      init.body = form; // FormData: the browser writes the multipart content type with its boundary
    }
    let res;
    try {
      res = await fetch(url, init);
    } catch {
      throw new ApiError(0, "The gyrocal service cannot be reached.", path);
    }
    if (res.status === 204) return null;
    if (raw && res.ok) return { text: await res.text(), headers: res.headers };
    let body = null;
    try {
      body = await res.json();
    } catch {
      body = null;
    }
    if (!res.ok) {
      const detail = body && body.detail ? (Array.isArray(body.detail) ? body.detail.join("; ") : body.detail) : res.statusText;
      const err = new ApiError(res.status, String(detail), path);
      if (res.status === 401 && !signingIn && this.onUnauthorized) this.onUnauthorized(err);
      throw err;
    }
    return body;
  }

  get(path, query) {
    return this.request("GET", path, { query });
  }

  post(path, json) {
    return this.request("POST", path, { json });
  }

  async health() {
    const h = await this.get("/health");
    this.authReads = Boolean(h.auth_reads);
    return h;
  }

  /** Sign in with a secret, or with a PIN ({pin}) on a tablet the service trusts with PINs. */
  async signIn(operator, secret, { pin } = {}) {
    const out = await this.request("POST", "/auth/login", { json: pin ? { operator, pin } : { operator, secret }, signingIn: true });
    this.token = out.token;
    this.operator = out.operator;
    sessionStorage.setItem(TOKEN_KEY, out.token);
    sessionStorage.setItem(OPERATOR_KEY, out.operator);
    return out;
  }

  forget() {
    this.token = null;
    this.operator = null;
    sessionStorage.removeItem(TOKEN_KEY);
    sessionStorage.removeItem(OPERATOR_KEY);
  }

  async signOut() {
    try {
      if (this.token) await this.request("POST", "/auth/logout");
    } catch {
      // signing out locally is what matters; an expired token is signed out anyway
    } finally {
      this.forget();
    }
  }

  /**
   * Follow a session's Server-Sent Events. onSnapshot(snapshot, eventName) for each; onLink(state) with
   * "open" | "retrying" when the stream connects or drops (it reconnects, resuming after the last event).
   * Returns a function that closes the stream.
   */
  follow(sessionId, onSnapshot, onLink) {
    return this.stream(`/sessions/${encodeURIComponent(sessionId)}/events`, EVENT_NAMES, onSnapshot, onLink);
  }

  /** Follow the fleet: onView(view) with the whole fleet view each time it changes on any gateway. */
  followFleet(onView, onLink) {
    return this.stream("/fleet/events", ["fleet"], onView, onLink);
  }

  /**
   * An EventSource that does not give up. The browser reconnects by itself when a stream drops, but not when the
   * service answers without a stream (a 503 while its store restarts, a gateway starting): then a new stream is
   * opened after a pause (1 s, doubling to 15 s), resuming after the last event it had.
   */
  stream(path, names, onData, onLink) {
    let closed = false;
    let es = null;
    let lastEventId = null;
    let retries = 0;
    let timer = null;
    const handler = (ev) => {
      if (closed) return;
      if (ev.lastEventId) lastEventId = ev.lastEventId;
      let data;
      try {
        data = JSON.parse(ev.data);
      } catch {
        return;
      }
      onData(data, ev.type);
    };
    const open = () => {
      const url = new URL(path, location.origin);
      if (this.authReads && this.token) url.searchParams.set("access_token", this.token);
      if (lastEventId !== null) url.searchParams.set("last_event_id", lastEventId);
      es = new EventSource(url);
      for (const name of names) es.addEventListener(name, handler);
      es.onopen = () => {
        retries = 0;
        if (!closed && onLink) onLink("open");
      };
      es.onerror = () => {
        if (closed) return;
        if (es.readyState === EventSource.CLOSED) timer = setTimeout(open, Math.min(1000 * 2 ** retries++, 15000));
        if (onLink) onLink("retrying");
      };
    };
    open();
    return () => {
      closed = true;
      clearTimeout(timer);
      es.close();
    };
  }
}
