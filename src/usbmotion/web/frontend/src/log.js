// The message log (the server's messages and the page's own errors) and the short toasts.

import { byId, el } from './format.js';

const KEPT = 500;
const TOAST_MS = 5000;

export class MessageLog {
  constructor() {
    this.list = byId('log');
    this.toasts = byId('toasts');
    this.lastSequence = 0;
  }

  // A server message; one seen before (a reconnect sends the last ones again) is skipped.
  message({ sequence, level, text }) {
    if (sequence <= this.lastSequence) {
      return;
    }
    this.lastSequence = sequence;
    this.add(level, text);
  }

  // A call the server did not take, or that did not reach it: in the log and as a toast.
  error(text) {
    this.add('error', text);
    this.toast(text);
  }

  add(level, text) {
    const atBottom = this.list.scrollTop + this.list.clientHeight >= this.list.scrollHeight - 4;
    const time = new Date().toLocaleTimeString([], { hour12: false });
    this.list.append(el('li', { class: `log-${level === 'error' ? 'error' : 'info'}` },
      el('time', {}, time), ' ', text));
    while (this.list.childElementCount > KEPT) {
      this.list.firstElementChild.remove();
    }
    if (atBottom) {
      this.list.scrollTop = this.list.scrollHeight;
    }
  }

  toast(text) {
    const toast = el('div', { class: 'toast', role: 'alert' }, text);
    this.toasts.append(toast);
    setTimeout(() => toast.remove(), TOAST_MS);
  }
}
