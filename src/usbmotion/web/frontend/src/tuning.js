// The tuning panel: a step response of one axis at rest, plotted with its overshoot and
// settling time.

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
    new ResizeObserver(() => {
      if (this.chart && this.chartBox.clientWidth) {
        this.chart.setSize({ width: this.chartBox.clientWidth, height: HEIGHT_PX });
      }
    }).observe(this.chartBox);
  }

  update(state) {
    this.idle = state.state === 'Idle' && !state.busy && state.homed;
    this.button.disabled = this.running || !this.idle;
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
