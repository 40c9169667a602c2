// The prediction before Run (POST /api/predict): the open program played on the axes'
// identified models before anything moves. Shows each axis's predicted peak and RMS
// following error, the lines predicted beyond the tolerance (marked in the program text, a
// click shows one), and after a run of the predicted program, predicted beside measured.

import { byId, el } from './format.js';

const MOTION_STATES = new Set(['Run', 'Hold', 'Paused', 'Jog', 'Homing', 'Stopping']);
const LINES_LISTED = 50;

// A following error in mm (or deg) with 4 decimals: a count is a few thousandths of a mm.
function fine(value) {
  return typeof value === 'number' && Number.isFinite(value) ? value.toFixed(4) : '—';
}

function unitOf(axis, state) {
  const figures = state && state.axes ? state.axes[axis] : null;
  return figures && figures.unit === 'deg' ? 'deg' : 'mm';
}

export class PredictionPanel {
  constructor(api, log, programText, { fromLine }) {
    this.api = api;
    this.log = log;
    this.programText = programText;
    this.fromLine = fromLine;
    this.button = byId('predict');
    this.tolerance = byId('tolerance');
    this.box = byId('prediction');
    this.comparisonBox = byId('prediction-comparison');
    this.state = null;
    this.connected = true;
    this.predicting = false;
    this.programName = null;
    this.sawRun = false;
    this.button.addEventListener('click', () => this.predict());
    this.tolerance.addEventListener('keydown', (event) => {
      if (event.key === 'Enter') {
        event.preventDefault();
        this.predict();
      }
    });
  }

  setConnected(connected) {
    this.connected = connected;
    if (this.state) {
      this.update(this.state);
    }
  }

  update(state) {
    this.state = state;
    const idle = this.connected && !state.busy && !MOTION_STATES.has(state.state);
    this.button.disabled = !(idle && state.program && !this.predicting);
    const name = state.program ? state.program.name : null;
    if (name !== this.programName) {
      this.programName = name;
      this.clear();
    }
    // A run of the open program ended: its report may carry the prediction.
    if (state.program && state.program.line > 0 && ['Run', 'Hold', 'Paused'].includes(state.state)) {
      this.sawRun = true;
    }
    if (this.sawRun && !state.busy) {
      this.sawRun = false;
      this.showComparison();
    }
  }

  // Another program is open: what was predicted is of the one before.
  clear() {
    this.box.hidden = true;
    this.box.replaceChildren();
    this.comparisonBox.hidden = true;
    this.comparisonBox.replaceChildren();
    this.programText.setMarked([]);
  }

  // The tolerance as the call takes it: null when empty, undefined when not a number.
  toleranceMm() {
    const text = this.tolerance.value.trim();
    if (!text) {
      return null;
    }
    const value = Number(text);
    if (!Number.isFinite(value) || value <= 0) {
      this.log.error(`Predict: tolerance ${JSON.stringify(text)} is not a positive number of mm`);
      return undefined;
    }
    return value;
  }

  async predict() {
    const tolerance = this.toleranceMm();
    if (tolerance === undefined) {
      return;
    }
    const body = { tolerance_mm: tolerance };
    const lineText = this.fromLine.value.trim();
    if (lineText) {
      body.from_line = Number(lineText);
    }
    this.predicting = true;
    this.button.disabled = true;
    this.box.hidden = false;
    this.box.setAttribute('aria-busy', 'true');
    this.box.replaceChildren(el('p', { class: 'hint' }, 'Predicting…'));
    try {
      this.show(await this.api.post('predict', body));
    } catch (error) {
      this.box.replaceChildren();
      this.box.hidden = true;
      this.log.error(`Predict: ${error.message}`);
    } finally {
      this.predicting = false;
      this.box.removeAttribute('aria-busy');
      if (this.state) {
        this.update(this.state);
      }
    }
  }

  show(prediction) {
    const rows = prediction.axes.map((axis) => {
      const unit = unitOf(axis.name, this.state);
      return el('tr', { 'data-testid': `predicted-${axis.name}` },
        el('th', { scope: 'row' }, axis.name),
        el('td', {}, `${fine(axis.max_error_mm)} ${unit}`),
        el('td', {}, `${fine(axis.rms_error_mm)} ${unit}`),
        el('td', {}, String(axis.max_error_line || '—')));
    });
    const table = el('table', { class: 'prediction-table' },
      el('caption', {}, 'Predicted following error'),
      el('thead', {}, el('tr', {},
        el('th', { scope: 'col' }, 'Axis'), el('th', { scope: 'col' }, 'Peak'),
        el('th', { scope: 'col' }, 'RMS'), el('th', { scope: 'col' }, 'At line'))),
      el('tbody', {}, ...rows));

    const sources = [...new Set(Object.values(prediction.motors))].join('; ');
    const speed = prediction.speed_ratio ? `, ${Math.round(prediction.speed_ratio)} × the program's time` : '';
    const from = prediction.from_line ? ` from line ${prediction.from_line}` : '';
    const facts = el('p', { class: 'hint' },
      `Played${from} on the axes' models (${sources}) in ${prediction.wall_s.toFixed(2)} s${speed}.`);
    const parts = [table, facts];
    if (!prediction.completed) {
      parts.push(el('p', { class: 'problem' }, `The predicted run did not complete: ${prediction.stop_reason}`));
    }

    const over = prediction.over_tolerance || [];
    if (prediction.tolerance_mm !== null && prediction.tolerance_mm !== undefined) {
      const tolerance = `${prediction.tolerance_mm} mm`;
      const summary = el('p', { class: over.length ? 'prediction-over' : 'prediction-within', 'data-testid': 'over-tolerance' },
        over.length ? `${over.length} line${over.length === 1 ? '' : 's'} beyond ${tolerance}`
          : `Every line within ${tolerance}`);
      parts.push(summary);
      if (over.length) {
        const list = el('ul', { class: 'line-list', 'aria-label': `Lines beyond ${tolerance}` });
        for (const row of over.slice(0, LINES_LISTED)) {
          const button = el('button', {
            type: 'button', class: 'line-button',
            title: `${row.axis} ${fine(row.peak_mm)} ${unitOf(row.axis, this.state)} predicted`,
          }, `Line ${row.line}`);
          button.addEventListener('click', () => this.programText.showLine(row.line));
          list.append(el('li', {}, button));
        }
        parts.push(list);
        if (over.length > LINES_LISTED) {
          parts.push(el('p', { class: 'hint' }, `and ${over.length - LINES_LISTED} more, marked in the program`));
        }
      }
    }
    this.box.replaceChildren(...parts);
    this.box.hidden = false;
    this.programText.setMarked(over.map((row) => row.line));
  }

  // After a run: the report's prediction (a run of the predicted program) beside what the
  // run measured, per axis.
  async showComparison() {
    let report;
    try {
      report = await this.api.get('report');
    } catch {
      return; // nothing has run, or the server is away: nothing to compare
    }
    if (!report.prediction) {
      this.comparisonBox.hidden = true;
      this.comparisonBox.replaceChildren();
      return;
    }
    const predicted = new Map(report.prediction.axes.map((axis) => [axis.name, axis]));
    const rows = [];
    for (const axis of report.axes) {
      const forecast = predicted.get(axis.name);
      if (!forecast) {
        continue;
      }
      rows.push(el('tr', { 'data-testid': `compared-${axis.name}` },
        el('th', { scope: 'row' }, axis.name),
        el('td', {}, fine(forecast.max_error_mm)), el('td', {}, fine(axis.max_error_mm)),
        el('td', {}, fine(forecast.rms_error_mm)), el('td', {}, fine(axis.rms_error_mm))));
    }
    const table = el('table', { class: 'prediction-table' },
      el('caption', {}, `Last run of ${report.program}: predicted beside measured (mm)`),
      el('thead', {}, el('tr', {},
        el('th', { scope: 'col' }, 'Axis'),
        el('th', { scope: 'col' }, 'Peak predicted'), el('th', { scope: 'col' }, 'Peak measured'),
        el('th', { scope: 'col' }, 'RMS predicted'), el('th', { scope: 'col' }, 'RMS measured'))),
      el('tbody', {}, ...rows));
    this.comparisonBox.replaceChildren(table);
    this.comparisonBox.hidden = false;
  }
}
