// The server's API (docs/dashboard.md): the token, the calls, and the live WebSocket.

const TOKEN_KEY = 'usbmotion.token';

// The token comes in the page's address once (usbmotion web prints it). It is kept for this
// tab only and taken out of the address bar, so a copied address or a screenshot of the
// bar does not carry it.
export function takeToken() {
  const address = new URL(window.location.href);
  const given = address.searchParams.get('token');
  if (given) {
    sessionStorage.setItem(TOKEN_KEY, given);
    address.searchParams.delete('token');
    history.replaceState(history.state, '', address.pathname + address.search + address.hash);
  }
  return sessionStorage.getItem(TOKEN_KEY) || '';
}

export class CallError extends Error {
  constructor(path, status, message) {
    super(message);
    this.path = path;
    this.status = status;
  }
}

// The page may be served under any prefix: calls go relative to the page's folder.
function apiUrl(path) {
  return new URL(`api/${path}`, document.baseURI);
}

export class Api {
  constructor(token) {
    this.token = token;
  }

  // One call: the answer's JSON, or a CallError with the server's `error` text.
  async call(path, { method = 'GET', body, json } = {}) {
    const headers = { Authorization: `Bearer ${this.token}` };
    let payload = body;
    if (json !== undefined) {
      headers['Content-Type'] = 'application/json';
      payload = JSON.stringify(json);
    }
    let response;
    try {
      response = await fetch(apiUrl(path), { method, headers, body: payload, cache: 'no-store' });
    } catch (error) {
      throw new CallError(path, 0, `the server cannot be reached (${error.message})`);
    }
    let answer = null;
    try {
      answer = await response.json();
    } catch {
      // Left null: the status still tells what happened.
    }
    if (!response.ok) {
      const text = answer && answer.error ? answer.error : `HTTP ${response.status}`;
      throw new CallError(path, response.status, text);
    }
    return answer;
  }

  get(path) {
    return this.call(path);
  }

  post(path, json) {
    return this.call(path, { method: 'POST', json: json === undefined ? {} : json });
  }

  liveUrl() {
    const address = apiUrl('live');
    address.protocol = address.protocol === 'https:' ? 'wss:' : 'ws:';
    address.searchParams.set('token', this.token);
    return address.href;
  }
}

const RECONNECT_FIRST_MS = 100;
const RECONNECT_MAX_MS = 2000;

// The WebSocket /api/live, opened again after every loss with a backoff up to 2 s.
// onOpen(reconnected) runs on each open; onData(object) on each message; onDown() when lost.
export class Live {
  constructor(api, { onOpen, onData, onDown }) {
    this.api = api;
    this.onOpen = onOpen;
    this.onData = onData;
    this.onDown = onDown;
    this.delayMs = RECONNECT_FIRST_MS;
    this.opened = false;
    this.socket = null;
  }

  start() {
    const socket = new WebSocket(this.api.liveUrl());
    this.socket = socket;
    socket.onopen = () => {
      this.delayMs = RECONNECT_FIRST_MS;
      const reconnected = this.opened;
      this.opened = true;
      this.onOpen(reconnected);
    };
    socket.onmessage = (event) => {
      this.onData(JSON.parse(event.data));
    };
    // onerror is always followed by onclose, where the retry is.
    socket.onerror = () => {};
    socket.onclose = () => {
      this.socket = null;
      this.onDown();
      setTimeout(() => this.start(), this.delayMs);
      this.delayMs = Math.min(this.delayMs * 2, RECONNECT_MAX_MS);
    };
  }
}
