// The controls: cycle, homing, overrides, jogging, work offsets, MDI and the program picker.
// Each sends its call; what follows is seen in the state and the messages. A control is
// disabled while the server could not take its call, never hidden.

import { byId, el } from './format.js';

const MOTION_STATES = new Set(['Run', 'Hold', 'Paused', 'Jog', 'Homing', 'Stopping']);
const JOG_KEYS = {
  ArrowRight: ['X', 1], ArrowLeft: ['X', -1],
  ArrowUp: ['Y', 1], ArrowDown: ['Y', -1],
  PageUp: ['Z', 1], PageDown: ['Z', -1],
};
// The jog pad's places for the first three axes; any others get a row of their own.
const PAD_PLACES = { 'X+': 'x-plus', 'X-': 'x-minus', 'Y+': 'y-plus', 'Y-': 'y-minus', 'Z+': 'z-plus', 'Z-': 'z-minus' };
const MDI_HISTORY_KEPT = 100;
const OVERRIDE_SEND_MS = 150;

// Whether a key pressed at `target` belongs to it: text fields, selects and sliders use the
// arrow keys, and so do the scrolled program text and log.
function keysTaken(target) {
  return target instanceof HTMLElement && (target.isContentEditable
    || target.closest('input, textarea, select, .program-text, .log') !== null);
}

export class Controls {
  constructor(api, log, { onProgramOpened }) {
    this.api = api;
    this.log = log;
    this.onProgramOpened = onProgramOpened;
    this.state = null;
    this.axisKey = '';
    this.buttons = {
      run: byId('run'), hold: byId('hold'), resume: byId('resume'), stop: byId('stop'),
      reset: byId('reset'), alarmReset: byId('alarm-reset'), homeAll: byId('home-all'),
      zeroAll: byId('zero-all'), jogCancel: byId('jog-cancel'), mdiSend: byId('mdi-send'),
      open: byId('program-open'), measureTool: byId('measure-tool'),
    };
    this.homeButtons = [];
    this.zeroButtons = [];
    this.jogButtons = [];
    this.jogStep = byId('jog-step');
    this.jogFeed = byId('jog-feed');
    this.feedOverride = byId('feed-override');
    this.feedOverrideValue = byId('feed-override-value');
    this.rapidChoices = [...document.querySelectorAll('input[name="rapid-override"]')];
    this.system = byId('coordinate-select');
    this.mdi = byId('mdi');
    this.fromLine = byId('from-line');
    this.programChoice = byId('program-choice');
    this.upload = byId('program-upload');
    this.mdiHistory = [];
    this.mdiIndex = 0;
    this.overrideSentAt = 0;
    this.overrideTimer = null;
    this.heldJog = null;
    // The open program's `problem` (GET /api/program) at its revision: a program that
    // cannot run from where the machine stands disables Run until it is planned again.
    this.programProblem = { revision: null, text: '' };
    this.connected = true;
    this.wire();
  }

  // A call; its refusal goes to the log and a toast. Resolves to the answer or null.
  async send(path, body, what) {
    try {
      return await this.api.post(path, body);
    } catch (error) {
      this.log.error(`${what}: ${error.message}`);
      return null;
    }
  }

  // Run: from the start, or from the line in "From line" (then cleared: the next Run is a
  // whole one unless a line is given again).
  async run() {
    const text = this.fromLine.value.trim();
    if (!text) {
      return this.send('run', undefined, 'Run');
    }
    const line = Number(text);
    if (!Number.isInteger(line) || line < 1) {
      this.log.error(`Run from line ${text}: a line number, 1 or more`);
      return null;
    }
    const answer = await this.send('run', { from_line: line }, `Run from line ${line}`);
    if (answer) {
      this.fromLine.value = '';
    }
    return answer;
  }

  // After a run that stopped, the line to resume from, offered (not filled in: a Run that
  // is not asked for from a line runs the whole program).
  offerResume(line) {
    if (Number.isInteger(line) && line > 0) {
      this.fromLine.placeholder = `stopped at ${line}`;
    }
  }

  wire() {
    const { buttons } = this;
    buttons.run.addEventListener('click', () => this.run());
    buttons.hold.addEventListener('click', () => this.send('hold', undefined, 'Hold'));
    buttons.resume.addEventListener('click', () => this.send('resume', undefined, 'Resume'));
    buttons.stop.addEventListener('click', () => this.send('stop', undefined, 'Stop'));
    for (const reset of [buttons.reset, buttons.alarmReset]) {
      reset.addEventListener('click', () => this.send('reset', undefined, 'Reset'));
    }
    buttons.homeAll.addEventListener('click', () => this.send('home', {}, 'Home'));
    buttons.zeroAll.addEventListener('click', () => this.zero(null));
    buttons.jogCancel.addEventListener('click', () => this.send('jog/cancel', undefined, 'Cancel jog'));
    buttons.measureTool.addEventListener('click', () => this.send('tool/measure', {}, 'Measure tool'));

    this.feedOverride.addEventListener('input', () => this.feedOverrideChanged());
    this.feedOverride.addEventListener('change', () => this.feedOverrideChanged());
    for (const choice of this.rapidChoices) {
      choice.addEventListener('change', () => {
        this.overrideSentAt = performance.now();
        this.send('overrides', { rapid: Number(choice.value) }, 'Rapid override');
      });
    }

    this.system.addEventListener('change', async () => {
      const name = this.system.selectedOptions[0].textContent;
      const answer = await this.send('offsets/select', { system: Number(this.system.value) },
        `Select ${name}`);
      if (!answer && this.state) {
        this.showSystem(this.state.coordinate_system);
      }
    });

    byId('mdi-form').addEventListener('submit', (event) => {
      event.preventDefault();
      this.sendMdi();
    });
    this.mdi.addEventListener('keydown', (event) => this.mdiKey(event));

    buttons.open.addEventListener('click', () => this.openChosen());
    this.upload.addEventListener('change', () => this.uploadChosen());

    document.addEventListener('keydown', (event) => this.jogKey(event, true));
    document.addEventListener('keyup', (event) => this.jogKey(event, false));
    // A continuous jog must not outlive the page's focus: a key or button released in
    // another window would never tell this one.
    window.addEventListener('blur', () => this.releaseJog());
  }

  // --- the state -----------------------------------------------------------------------

  // While the live connection is down no call can be answered and the state shown is
  // old: every control that calls the machine is disabled until it is back.
  setConnected(connected) {
    this.connected = connected;
    if (this.state) {
      this.update(this.state);
    }
  }

  update(state) {
    this.state = state;
    const key = state.axis_order.join(',');
    if (key !== this.axisKey) {
      this.axisKey = key;
      this.buildAxes(state.axis_order);
    }
    const name = state.state;
    const alarm = name === 'Alarm';
    const idle = this.connected && !state.busy && !MOTION_STATES.has(name);
    const held = this.connected && (name === 'Hold' || name === 'Paused' || state.hold_pending);
    const { buttons } = this;
    const problem = state.program && state.program.revision === this.programProblem.revision
      && this.programProblem.text;
    buttons.run.disabled = !(idle && !alarm && state.program && !problem);
    buttons.hold.disabled = !(this.connected && (name === 'Run' || name === 'Jog') && !state.hold_pending);
    buttons.resume.disabled = !held;
    buttons.stop.disabled = !(this.connected && (state.busy || held || MOTION_STATES.has(name)));
    buttons.reset.disabled = !this.connected;
    buttons.alarmReset.disabled = !this.connected;
    const canHome = idle && !alarm;
    buttons.homeAll.disabled = !canHome;
    for (const button of this.homeButtons) {
      button.disabled = !canHome;
    }
    const canZero = idle && !alarm && state.homed;
    buttons.zeroAll.disabled = !canZero;
    for (const button of this.zeroButtons) {
      button.disabled = !canZero;
    }
    const continuous = this.jogStep.value === 'continuous';
    // A continuous jog's own button stays enabled while it runs: releasing it ends the jog.
    const canJog = idle && !alarm && state.homed;
    for (const button of this.jogButtons) {
      button.disabled = !canJog && !(continuous && this.heldJog && this.heldJog.button === button);
    }
    buttons.jogCancel.disabled = !(this.connected && name === 'Jog');
    // The tool in the spindle from Idle; at a program's M6 pause the new one, the program
    // then going on by itself.
    buttons.measureTool.hidden = !state.tool_setter;
    buttons.measureTool.disabled = !((idle && !alarm && state.homed)
      || (this.connected && state.tool_change));
    buttons.mdiSend.disabled = !this.connected || alarm || !state.homed;
    buttons.open.disabled = !idle || this.programChoice.options.length === 0;
    this.upload.disabled = !idle;
    this.upload.closest('label').classList.toggle('disabled', !idle);

    if (performance.now() - this.overrideSentAt > 1000 && !this.feedOverride.matches(':active')) {
      this.feedOverride.value = String(state.feed_override);
      this.feedOverrideValue.value = `${state.feed_override} %`;
      for (const choice of this.rapidChoices) {
        choice.checked = Number(choice.value) === state.rapid_override;
      }
    }
    if (document.activeElement !== this.system) {
      this.showSystem(state.coordinate_system);
    }
  }

  showSystem(name) {
    for (const option of this.system.options) {
      if (option.textContent === name) {
        this.system.value = option.value;
      }
    }
  }

  buildAxes(axes) {
    const homeRow = byId('home-buttons');
    const zeroRow = byId('zero-buttons');
    for (const button of [...this.homeButtons, ...this.zeroButtons]) {
      button.remove();
    }
    this.homeButtons = axes.map((axis) => {
      const button = el('button', { type: 'button' }, `Home ${axis}`);
      button.addEventListener('click', () => this.send('home', { axes: [axis] }, `Home ${axis}`));
      homeRow.append(button);
      return button;
    });
    this.zeroButtons = axes.map((axis) => {
      const button = el('button', { type: 'button' }, `Zero ${axis}`);
      button.addEventListener('click', () => this.zero([axis]));
      zeroRow.insertBefore(button, this.buttons.zeroAll);
      return button;
    });

    const pad = byId('jog-pad');
    pad.replaceChildren();
    this.jogButtons = [];
    for (const axis of axes) {
      for (const [sign, direction] of [['+', 1], ['-', -1]]) {
        const place = PAD_PLACES[`${axis}${sign}`] || 'extra';
        const shown = `${axis}${sign === '-' ? '−' : '+'}`;
        const button = el('button', {
          type: 'button', class: `jog-button jog-${place}`, 'aria-label': `Jog ${axis}${sign}`,
        }, shown);
        this.wireJogButton(button, axis, direction);
        pad.append(button);
        this.jogButtons.push(button);
      }
    }

    const tuneAxis = byId('tune-axis');
    tuneAxis.replaceChildren(...axes.map((axis) => el('option', { value: axis }, axis)));
  }

  // --- overrides and offsets -----------------------------------------------------------

  feedOverrideChanged() {
    const percent = Number(this.feedOverride.value);
    this.feedOverrideValue.value = `${percent} %`;
    this.overrideSentAt = performance.now();
    // While the slider is dragged the value goes at most every OVERRIDE_SEND_MS; the last
    // one always goes.
    clearTimeout(this.overrideTimer);
    this.overrideTimer = setTimeout(() => {
      this.overrideSentAt = performance.now();
      this.send('overrides', { feed: percent }, 'Feed override');
    }, OVERRIDE_SEND_MS);
  }

  zero(axes) {
    const system = Number(this.system.value);
    const body = axes ? { axes, system } : { system };
    const what = axes ? `Zero ${axes.join(' ')}` : 'Zero all';
    return this.send('offsets/zero', body, what);
  }

  // --- jogging ---------------------------------------------------------------------------

  jogFeedMmMin() {
    const feed = Number(this.jogFeed.value);
    if (!(feed > 0)) {
      this.log.error(`Jog: feed ${JSON.stringify(this.jogFeed.value)} is not a positive number of mm/min`);
      return null;
    }
    return feed;
  }

  jogStepMm() {
    return this.jogStep.value === 'continuous' ? null : Number(this.jogStep.value);
  }

  jogBy(axis, direction) {
    const feed = this.jogFeedMmMin();
    if (feed === null) {
      return;
    }
    this.send('jog', { moves: { [axis]: direction * this.jogStepMm() }, feed_mm_min: feed,
      continuous: false }, `Jog ${axis}${direction > 0 ? '+' : '-'}`);
  }

  // A continuous jog runs from the press to the release. The cancel goes only after the
  // jog's call has answered, so a quick tap cannot cancel before the jog starts and leave
  // it running.
  holdJog(axis, direction, button) {
    if (this.heldJog) {
      return;
    }
    const feed = this.jogFeedMmMin();
    if (feed === null) {
      return;
    }
    const started = this.send('jog', { moves: { [axis]: direction }, feed_mm_min: feed,
      continuous: true }, `Jog ${axis}${direction > 0 ? '+' : '-'}`);
    this.heldJog = { button, started };
  }

  async releaseJog() {
    const held = this.heldJog;
    if (!held) {
      return;
    }
    this.heldJog = null;
    const answer = await held.started;
    if (answer) {
      await this.send('jog/cancel', undefined, 'Cancel jog');
    }
  }

  wireJogButton(button, axis, direction) {
    button.addEventListener('click', () => {
      if (this.jogStepMm() !== null) {
        this.jogBy(axis, direction);
      }
    });
    button.addEventListener('pointerdown', (event) => {
      if (this.jogStepMm() === null && event.button === 0) {
        button.setPointerCapture(event.pointerId);
        this.holdJog(axis, direction, button);
      }
    });
    for (const end of ['pointerup', 'pointercancel', 'lostpointercapture']) {
      button.addEventListener(end, () => this.releaseJog());
    }
    // Enter or Space held on the focused button jogs continuously like a held pointer.
    button.addEventListener('keydown', (event) => {
      if (this.jogStepMm() === null && (event.key === ' ' || event.key === 'Enter')) {
        event.preventDefault();
        if (!event.repeat) {
          this.holdJog(axis, direction, button);
        }
      }
    });
    button.addEventListener('keyup', (event) => {
      if (event.key === ' ' || event.key === 'Enter') {
        this.releaseJog();
      }
    });
    button.addEventListener('contextmenu', (event) => event.preventDefault());
  }

  jogKey(event, down) {
    if (event.key === 'Escape') {
      if (down && (this.heldJog || (this.state && this.state.state === 'Jog'))) {
        this.heldJog = null;
        this.send('jog/cancel', undefined, 'Cancel jog');
      }
      return;
    }
    const move = JOG_KEYS[event.key];
    if (!move || keysTaken(event.target) || event.altKey || event.ctrlKey || event.metaKey) {
      return;
    }
    const [axis, direction] = move;
    if (!this.state || !this.state.axis_order.includes(axis)) {
      return;
    }
    event.preventDefault();
    const continuous = this.jogStepMm() === null;
    if (!down) {
      if (continuous) {
        this.releaseJog();
      }
      return;
    }
    if (event.repeat) {
      return;
    }
    const button = this.jogButtons.find((b) => b.getAttribute('aria-label') === `Jog ${axis}${direction > 0 ? '+' : '-'}`);
    if (button && button.disabled) {
      this.log.toast(`Jog ${axis}: not now (the machine is ${this.state.state}${this.state.homed ? '' : ', not homed'})`);
      return;
    }
    if (continuous) {
      this.holdJog(axis, direction, button);
    } else {
      this.jogBy(axis, direction);
    }
  }

  // --- MDI ---------------------------------------------------------------------------------

  async sendMdi() {
    const line = this.mdi.value.trim();
    if (!line) {
      return;
    }
    if (this.mdiHistory[this.mdiHistory.length - 1] !== line) {
      this.mdiHistory.push(line);
      if (this.mdiHistory.length > MDI_HISTORY_KEPT) {
        this.mdiHistory.shift();
      }
    }
    this.mdiIndex = this.mdiHistory.length;
    this.mdi.value = '';
    // The server logs the line it took ("> G0 X10"); a refusal is logged here with the line.
    await this.send('mdi', { line }, `MDI ${line}`);
  }

  mdiKey(event) {
    if (event.key !== 'ArrowUp' && event.key !== 'ArrowDown') {
      return;
    }
    event.preventDefault();
    const step = event.key === 'ArrowUp' ? -1 : 1;
    this.mdiIndex = Math.min(Math.max(this.mdiIndex + step, 0), this.mdiHistory.length);
    this.mdi.value = this.mdiHistory[this.mdiIndex] || '';
  }

  // --- programs ----------------------------------------------------------------------------

  async loadCatalogue() {
    let catalogue;
    try {
      catalogue = await this.api.get('programs');
    } catch (error) {
      this.log.error(`Programs: ${error.message}`);
      return;
    }
    const options = [];
    for (const demo of catalogue.demos || []) {
      const title = demo.title ? `${demo.title} (${demo.name})` : demo.name;
      options.push(el('option', { value: `demo:${demo.number}` }, `Demo ${demo.number}: ${title}`));
    }
    for (const file of catalogue.files || []) {
      options.push(el('option', { value: `file:${file}` }, file));
    }
    this.programChoice.replaceChildren(...options);
    if (this.state) {
      this.update(this.state);
    }
  }

  async openChosen() {
    const [kind, ...rest] = this.programChoice.value.split(':');
    const value = rest.join(':');
    const body = kind === 'demo' ? { demo: Number(value) } : { file: value };
    const program = await this.send('program/open', body, `Open ${value}`);
    if (program) {
      this.onProgramOpened(program);
    }
  }

  async uploadChosen() {
    const file = this.upload.files[0];
    if (!file) {
      return;
    }
    let program = null;
    try {
      program = await this.api.call(`program/upload?name=${encodeURIComponent(file.name)}`, {
        method: 'POST', body: file,
      });
    } catch (error) {
      this.log.error(`Upload ${file.name}: ${error.message}`);
    }
    this.upload.value = '';
    if (program) {
      this.onProgramOpened(program);
    }
  }
}
