// The digital read-out: each axis's positions and following error, the state beside them.

import { byId, el, mm, setText } from './format.js';

// An angle in degrees, 0 to 360.
function angle(value) {
  return typeof value === 'number' && Number.isFinite(value)
    ? mm(((value % 360) + 360) % 360) : mm(value);
}

const STATE_CLASSES = ['Idle', 'Run', 'Hold', 'Paused', 'Jog', 'Homing', 'Stopping', 'Alarm'];

export class Readout {
  constructor() {
    this.rows = byId('dro-rows');
    this.state = byId('state');
    this.homed = byId('homed');
    this.motion = byId('motion');
    this.pause = byId('pause-text');
    this.feed = byId('feed');
    this.overrides = byId('overrides-shown');
    this.tool = byId('tool');
    this.spindleFact = byId('spindle-fact');
    this.spindle = byId('spindle');
    this.outputsFact = byId('outputs-fact');
    this.outputs = byId('outputs');
    this.system = byId('coordinate-system');
    this.offsets = byId('work-offsets');
    this.cells = new Map();
    this.axisKey = '';
  }

  // The rows follow axis_order; they are built again only if the machine's axes change.
  build(axes) {
    this.cells.clear();
    this.rows.replaceChildren();
    for (const axis of axes) {
      const figure = (name, extra = '') => el('span', {
        class: `figure ${extra}`, 'data-testid': `dro-${axis}-${name}`,
      });
      const cells = {
        work: figure('work', 'figure-main'),
        workCommanded: figure('work-commanded', 'figure-commanded'),
        machine: figure('machine', 'figure-main'),
        machineCommanded: figure('machine-commanded', 'figure-commanded'),
        error: figure('error'),
        row: null,
      };
      cells.row = el('tr', {},
        el('th', { scope: 'row', class: 'axis-name' }, axis),
        el('td', {}, cells.work, cells.workCommanded),
        el('td', {}, cells.machine, cells.machineCommanded),
        el('td', { class: 'error-cell' }, cells.error));
      this.rows.append(cells.row);
      this.cells.set(axis, cells);
    }
  }

  show(state) {
    const axes = state.axis_order;
    const key = axes.join(',');
    if (key !== this.axisKey) {
      this.axisKey = key;
      this.build(axes);
    }
    for (const axis of axes) {
      const cells = this.cells.get(axis);
      const reading = state.axes[axis];
      if (!reading) {
        continue;
      }
      // A wrapped rotary axis turns on without end: its angle is shown modulo 360.
      const place = reading.wrapped ? angle : mm;
      setText(cells.work, place(reading.work_mm));
      setText(cells.workCommanded, place(reading.commanded_work_mm));
      setText(cells.machine, place(reading.machine_mm));
      setText(cells.machineCommanded, place(reading.commanded_mm));
      setText(cells.error, mm(reading.following_error_mm));
      cells.row.title = reading.unit === 'deg' ? `${axis}: degrees` : `${axis}: mm`;
      cells.row.classList.toggle('axis-limit', Boolean(reading.limit));
      cells.row.classList.toggle('axis-fault', Boolean(reading.fault));
    }

    setText(this.state, state.state);
    for (const name of STATE_CLASSES) {
      this.state.classList.toggle(`state-${name.toLowerCase()}`, state.state === name);
    }
    setText(this.homed, state.homed ? 'homed' : 'not homed');
    this.homed.classList.toggle('fact-warn', !state.homed);
    setText(this.motion, state.at_rest ? 'at rest' : 'moving');
    this.pause.hidden = !state.pause;
    setText(this.pause, state.pause || '');

    setText(this.feed, Number.isFinite(state.feed_mm_min) ? state.feed_mm_min.toFixed(0) : '—');
    setText(this.overrides, `${state.feed_override} %, rapid ${state.rapid_override} %`);
    const length = state.tool_length_mm ? ` (length ${mm(state.tool_length_mm)} mm)` : '';
    setText(this.tool, `T${state.tool}${length}`);
    // The coolant and laser outputs as the devices have them; the probe when it touches.
    const outputs = state.outputs || {};
    const names = Object.keys(outputs);
    this.outputsFact.hidden = names.length === 0 && !state.probe;
    const shown = names.map((name) => (name === 'laser'
      ? `laser ${(outputs[name] / 10).toFixed(0)} %` : `${name} ${outputs[name] ? 'on' : 'off'}`));
    if (state.probe) {
      shown.push('probe touching');
    }
    setText(this.outputs, shown.join(', '));
    // The spindle's speed as its encoder measures it, and the speed asked when it differs.
    const spindle = state.spindle;
    this.spindleFact.hidden = !spindle;
    if (spindle) {
      const measured = Math.abs(spindle.measured_rpm).toFixed(0);
      const asked = Math.abs(spindle.commanded_rpm).toFixed(0);
      const turn = spindle.commanded_rpm < 0 ? ' CCW' : '';
      setText(this.spindle, spindle.at_speed ? `${measured} rpm${turn}`
        : `${measured} rpm${turn} (to ${asked})`);
    }
    setText(this.system, state.coordinate_system);
    const offsets = state.work_offset_mm || {};
    setText(this.offsets, axes.map((axis) => `${axis} ${mm(offsets[axis])}`).join('  '));
  }
}
