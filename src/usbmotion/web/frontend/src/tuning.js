// The tuning panel: a step response of one axis at rest, plotted with its overshoot and
// settling time; and the automatic tuning (usbmotion tune --auto): the axis identified,
// its gains placed, checked, predicted beside measured, written to the machine file if asked.

import uPlot from 'uplot';
import { byId, setText } from './format.js';

const HEIGHT_PX = 220;

export class TuningPanel {
  constructor(api, log) {
    this.api = api;
    this.log = log;
    this.axis = byId('tune-axis');
    this.step = byId('tune-step');
    this.button = byId('tune-run');
    this.result = byId('tune-result');
    this.chartBox = byId('tune-chart');
    this.chart = null;
    this.running = false;
    this.idle = false;
    byId('tune-form').addEventListener('submit', (event) => {
      event.preventDefault();
      this.run();
    });
    this.autoTravel = byId('auto-travel');
    this.autoWrite = byId('auto-write');
    this.autoButton = byId('auto-run');
    this.autoResult = byId('auto-result');
    byId('auto-form').addEventListener('submit', (event) => {
      event.preventDefault();
      this.runAuto();
    });
    new ResizeObserver(() => {
      if (this.chart && this.chartBox.clientWidth) {
        this.chart.setSize({ width: this.chartBox.clientWidth, height: HEIGHT_PX });
      }
    }).observe(this.chartBox);
  }

  update(state) {
    this.idle = state.state === 'Idle' && !state.busy && state.homed;
    this.button.disabled = this.running || !this.idle;
    this.autoIdle = state.state === 'Idle' && !state.busy;
    this.autoButton.disabled = this.running || !this.autoIdle;
  }

  async runAuto() {
    const axis = this.axis.value;
    const travelMm = Number(this.autoTravel.value);
    if (!Number.isFinite(travelMm) || travelMm === 0) {
      this.log.error(`Tuning: travel ${JSON.stringify(this.autoTravel.value)} is not a distance in mm (not 0)`);
      return;
    }
    const write = this.autoWrite.checked;
    this.running = true;
    this.autoButton.disabled = true;
    this.button.disabled = true;
    this.autoResult.replaceChildren(document.createTextNode(
      `identifying ${axis} within ${travelMm} mm of where it stands…`));
    try {
      const answer = await this.api.post('tune/auto', { axis, travel_mm: travelMm, write });
      this.showAuto(answer);
    } catch (error) {
      this.autoResult.replaceChildren();
      this.log.error(`Tuning ${axis} automatically: ${error.message}`);
    } finally {
      this.running = false;
      this.autoButton.disabled = !this.autoIdle;
      this.button.disabled = !this.idle;
    }
  }

  showAuto(answer) {
    const m = answer.model;
    const g = answer.gains;
    const loop = answer.loop;
    const lines = [
      `${answer.axis}: time constant ${(m.time_constant_s * 1000).toFixed(2)} ms,`
        + ` ${m.speed_per_volt_counts_s.toPrecision(4)} counts/s per V,`
        + ` Coulomb ${m.coulomb_v.toFixed(3)} V`,
      `gains kp ${g.kp} ki ${g.ki} kd ${g.kd}: crossover ${loop.crossover_hz.toFixed(1)} Hz,`
        + ` phase margin ${loop.phase_margin_deg === null ? '—' : loop.phase_margin_deg.toFixed(1)} deg,`
        + ` gain margin ${loop.gain_margin_db === null ? '—' : loop.gain_margin_db.toFixed(1)} dB`,
      answer.written_to ? `written to ${answer.written_to}` : 'not written: the axis keeps the file\'s gains',
    ];
    const table = document.createElement('table');
    table.className = 'auto-checks';
    const head = table.createTHead().insertRow();
    for (const title of ['check', 'figure', 'predicted', 'measured']) {
      const cell = document.createElement('th');
      cell.textContent = title;
      head.appendChild(cell);
    }
    const body = table.createTBody();
    const shown = [
      ['overshoot_pct', 'overshoot (%)', 1, 2],
      ['settling_time_s', 'settling (ms)', 1000, 1],
      ['peak_following_error_counts', 'peak error (counts)', 1, 0],
    ];
    for (const [what, check] of Object.entries(answer.checks)) {
      for (const [key, label, factor, digits] of shown) {
        const row = body.insertRow();
        const pair = check[key];
        for (const text of [what, label,
          pair.predicted === null ? '—' : (pair.predicted * factor).toFixed(digits),
          pair.measured === null ? '—' : (pair.measured * factor).toFixed(digits)]) {
          row.insertCell().textContent = text;
        }
      }
    }
    const paragraphs = lines.map((text) => {
      const p = document.createElement('p');
      p.textContent = text;
      return p;
    });
    this.autoResult.replaceChildren(...paragraphs, table);
  }

  async run() {
    const axis = this.axis.value;
    const stepMm = Number(this.step.value);
    if (!(stepMm > 0)) {
      this.log.error(`Tuning: step ${JSON.stringify(this.step.value)} is not a positive number of mm`);
      return;
    }
    this.running = true;
    this.button.disabled = true;
    setText(this.result, `step response of ${axis}, ${stepMm} mm…`);
    try {
      const answer = await this.api.post('tune', { axis, step_mm: stepMm });
      this.show(axis, stepMm, answer);
    } catch (error) {
      setText(this.result, '');
      this.log.error(`Tuning ${axis}: ${error.message}`);
    } finally {
      this.running = false;
      this.button.disabled = !this.idle;
    }
  }

  show(axis, stepMm, answer) {
    const overshoot = Number.isFinite(answer.overshoot_percent)
      ? `${answer.overshoot_percent.toFixed(1)} %` : '—';
    const settling = Number.isFinite(answer.settling_s)
      ? `${(answer.settling_s * 1000).toFixed(0)} ms` : 'did not settle';
    const rise = Number.isFinite(answer.rise_s) ? `, rise ${(answer.rise_s * 1000).toFixed(1)} ms` : '';
    setText(this.result, `${axis}, step ${stepMm} mm: overshoot ${overshoot}, settling ${settling}${rise}`);
    const data = [answer.time_s, answer.commanded_mm, answer.measured_mm];
    if (this.chart) {
      this.chart.setData(data);
      return;
    }
    this.chart = new uPlot({
      width: Math.max(200, this.chartBox.clientWidth),
      height: HEIGHT_PX,
      scales: { x: { time: false } },
      axes: [
        { label: 'time (s)', size: 40 },
        { label: 'position (mm)', size: 64 },
      ],
      series: [
        { label: 't (s)', value: (self, v) => (v === null ? '—' : v.toFixed(4)) },
        { label: 'commanded', stroke: '#5d6b7a', width: 1.5, dash: [6, 4] },
        { label: 'measured', stroke: '#d0342c', width: 1.5 },
      ],
    }, data, this.chartBox);
  }
}
