// The following-error strip charts: one per axis, the last 10 s, a point per push.

import uPlot from 'uplot';
import { el } from './format.js';

const WINDOW_S = 10;
// The smallest half-height of a chart, so a machine at rest does not fill it with noise.
const MIN_SPAN_MM = 0.005;
const HEIGHT_PX = 104;
export const AXIS_COLOURS = { X: '#d0342c', Y: '#1f8a3a', Z: '#2456c8' };
const OTHER_COLOUR = '#8a4fc0';

export class ErrorCharts {
  // onDraw(timeMs) is called once per redraw of the charts (the first chart's draw), so the
  // page can count redraws against pushes.
  constructor(container, { onDraw }) {
    this.container = container;
    this.onDraw = onDraw;
    this.charts = new Map();
    this.times = [];
    this.errors = new Map();
    this.axisKey = '';
    new ResizeObserver(() => this.resize()).observe(container);
  }

  build(axes) {
    for (const chart of this.charts.values()) {
      chart.destroy();
    }
    this.container.replaceChildren();
    this.charts.clear();
    this.errors = new Map(axes.map((axis) => [axis, []]));
    this.times = [];
    const width = this.width();
    axes.forEach((axis, index) => {
      const holder = el('div', { class: 'chart', 'data-testid': `chart-${axis}` },
        el('span', { class: 'chart-axis' }, axis));
      this.container.append(holder);
      const hooks = index === 0 ? { draw: [() => this.onDraw(performance.now())] } : {};
      const chart = new uPlot({
        width,
        height: HEIGHT_PX,
        legend: { show: false },
        cursor: { drag: { x: false, y: false } },
        scales: {
          x: {
            time: false,
            range: (self, min, max) => [max - WINDOW_S, max],
          },
          y: {
            range: (self, min, max) => {
              const span = Math.max(Math.abs(min), Math.abs(max), MIN_SPAN_MM) * 1.1;
              return [-span, span];
            },
          },
        },
        axes: [
          {
            size: 28,
            // The ticks read as seconds before now.
            values: (self, ticks) => {
              const now = self.data[0].length ? self.data[0][self.data[0].length - 1] : 0;
              return ticks.map((tick) => `${Math.round(tick - now) || 0} s`);
            },
          },
          { size: 56, space: 16, values: (self, ticks) => ticks.map((tick) => tick.toFixed(3)) },
        ],
        series: [
          {},
          { label: `${axis} peak error (mm)`, stroke: AXIS_COLOURS[axis] || OTHER_COLOUR, width: 1.5,
            points: { show: false } },
        ],
        hooks,
      }, [[], []], holder);
      this.charts.set(axis, chart);
    });
  }

  width() {
    return Math.max(200, this.container.clientWidth);
  }

  resize() {
    const width = this.width();
    for (const chart of this.charts.values()) {
      if (chart.width !== width) {
        chart.setSize({ width, height: HEIGHT_PX });
      }
    }
  }

  // One push: every axis's peak error since the push before, plotted at once (not batched
  // to animation frames, so no push is merged into another's redraw).
  push(state) {
    const axes = state.axis_order;
    const key = axes.join(',');
    if (key !== this.axisKey) {
      this.axisKey = key;
      this.build(axes);
    }
    const now = performance.now() / 1000;
    this.times.push(now);
    for (const axis of axes) {
      const reading = state.axes[axis];
      this.errors.get(axis).push(reading ? reading.peak_error_mm : null);
    }
    let old = 0;
    while (old < this.times.length && this.times[old] < now - WINDOW_S) {
      old += 1;
    }
    // Trimmed in batches: splicing the front of the arrays on every push costs more.
    if (old > 50) {
      this.times.splice(0, old);
      for (const values of this.errors.values()) {
        values.splice(0, old);
      }
    }
    for (const [axis, chart] of this.charts) {
      chart.setData([this.times, this.errors.get(axis)]);
    }
  }
}
