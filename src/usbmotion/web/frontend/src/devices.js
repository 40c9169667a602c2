// The devices panel: each axis's device parameters, editable one at a time.

import { byId, el, setText } from './format.js';

export class DevicesPanel {
  constructor(api, log) {
    this.api = api;
    this.log = log;
    this.panel = byId('devices-panel');
    this.box = byId('devices');
    this.status = byId('devices-status');
    this.flash = byId('write-flash');
    this.reload = byId('devices-reload');
    // Read when first opened, not at load: reading every parameter of every device is
    // work for the machine, and the server refuses it while the machine is busy.
    this.panel.addEventListener('toggle', () => {
      if (this.panel.open && !this.box.hasChildNodes()) {
        this.load();
      }
    });
    this.reload.addEventListener('click', () => this.load());
  }

  async load() {
    setText(this.status, 'reading the devices…');
    let answer;
    try {
      answer = await this.api.get('devices');
    } catch (error) {
      setText(this.status, `the devices cannot be read: ${error.message}`);
      return;
    }
    setText(this.status, '');
    this.box.replaceChildren(...answer.devices.map((device) => this.table(device)));
  }

  table(device) {
    const rows = device.parameters.map((parameter) => {
      const id = `parameter-${device.axis}-${parameter.name}`;
      const input = el('input', {
        id, type: 'text', value: String(parameter.value), spellcheck: 'false', autocomplete: 'off',
        title: `allowed: ${parameter.allowed}`,
      });
      const answer = el('td', { class: 'parameter-answer' }, parameter.storage);
      input.addEventListener('change', () => this.set(device.axis, parameter, input, answer));
      return el('tr', {},
        el('th', { scope: 'row' },
          el('label', { for: id }, parameter.name),
          el('span', { class: 'parameter-meaning' }, parameter.meaning)),
        el('td', { class: 'parameter-value' }, input, el('span', { class: 'unit' }, parameter.unit)),
        answer);
    });
    return el('table', { class: 'parameters' },
      el('caption', {}, device.label || device.axis, el('span', { class: 'port' }, ` ${device.port || ''}`)),
      el('thead', {}, el('tr', {},
        el('th', { scope: 'col' }, 'Parameter'), el('th', { scope: 'col' }, 'Value'),
        el('th', { scope: 'col' }, 'Kept in'))),
      el('tbody', {}, ...rows));
  }

  // The value goes as typed: the server checks it as `usbmotion set` does and answers the
  // value the device then holds.
  async set(axis, parameter, input, answerCell) {
    const value = input.value.trim();
    const flash = this.flash.checked;
    try {
      const answer = await this.api.post(`devices/${encodeURIComponent(axis)}/parameters`,
        { name: parameter.name, value, flash });
      input.value = String(answer.value);
      parameter.value = answer.value;
      setText(answerCell, `set: ${answer.storage}`);
    } catch (error) {
      input.value = String(parameter.value);
      setText(answerCell, 'refused');
      this.log.error(`${axis} ${parameter.name} = ${value}: ${error.message}`);
    }
  }
}
