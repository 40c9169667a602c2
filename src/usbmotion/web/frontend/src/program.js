// The program text with its line numbers and the line executing now, and the progress.
//
// Only the rows in sight (and a margin) are in the document: an uploaded program may have
// hundreds of thousands of lines. Every row has the same height (--row-height in style.css).

import { byId, duration, el, setText } from './format.js';

const MARGIN_ROWS = 30;

export class ProgramText {
  constructor() {
    this.box = byId('program-text');
    this.name = byId('program-name');
    this.problem = byId('program-problem');
    this.progress = byId('progress');
    this.progressText = byId('progress-text');
    this.eta = byId('eta');
    this.lines = [];
    this.current = 0;
    // The lines a prediction put beyond the tolerance.
    this.marked = new Set();
    this.rendered = { first: -1, last: -1 };
    this.sizer = el('div', { class: 'program-sizer' });
    this.list = el('ol', { class: 'program-lines' });
    this.sizer.append(this.list);
    this.box.append(this.sizer);
    this.box.addEventListener('scroll', () => this.renderRows());
    new ResizeObserver(() => this.renderRows(true)).observe(this.box);
  }

  rowHeight() {
    return parseFloat(getComputedStyle(this.box).getPropertyValue('--row-height')) || 20;
  }

  setProgram(program) {
    this.lines = program ? program.lines : [];
    setText(this.name, program ? program.name : '');
    const problem = program ? [program.problem, ...(program.warnings || [])].filter(Boolean) : [];
    this.problem.hidden = problem.length === 0;
    setText(this.problem, problem.join(' '));
    this.sizer.style.height = `${this.lines.length * this.rowHeight()}px`;
    this.box.scrollTop = 0;
    this.renderRows(true);
    this.scrollToCurrent();
  }

  renderRows(force = false) {
    const height = this.rowHeight();
    const first = Math.max(0, Math.floor(this.box.scrollTop / height) - MARGIN_ROWS);
    const last = Math.min(this.lines.length,
      Math.ceil((this.box.scrollTop + this.box.clientHeight) / height) + MARGIN_ROWS);
    if (!force && first === this.rendered.first && last === this.rendered.last) {
      return;
    }
    this.rendered = { first, last };
    const rows = [];
    for (let index = first; index < last; index += 1) {
      const number = index + 1;
      const row = el('li', { class: 'program-line', 'data-line': number },
        el('span', { class: 'gutter', 'aria-hidden': 'true' }, String(number)),
        el('span', { class: 'code' }, this.lines[index]));
      if (number === this.current) {
        row.classList.add('current');
        row.setAttribute('aria-current', 'true');
      }
      if (this.marked.has(number)) {
        row.classList.add('over-tolerance');
        row.title = 'predicted beyond the tolerance';
      }
      rows.push(row);
    }
    this.list.style.transform = `translateY(${first * height}px)`;
    this.list.start = first + 1;
    this.list.replaceChildren(...rows);
  }

  // The line the devices execute now, highlighted and scrolled into view.
  setCurrent(line) {
    if (line === this.current) {
      return;
    }
    const before = this.list.querySelector('.current');
    if (before) {
      before.classList.remove('current');
      before.removeAttribute('aria-current');
    }
    this.current = line;
    this.scrollToCurrent();
    const row = this.list.querySelector(`[data-line="${line}"]`);
    if (row) {
      row.classList.add('current');
      row.setAttribute('aria-current', 'true');
    }
  }

  // Marks `lines` (and only those) as predicted beyond the tolerance.
  setMarked(lines) {
    if (this.marked.size === 0 && lines.length === 0) {
      return;
    }
    this.marked = new Set(lines);
    this.renderRows(true);
  }

  // Line `line` scrolled into view, a third of the way down, and given the focus ring.
  showLine(line) {
    if (line <= 0 || line > this.lines.length) {
      return;
    }
    const height = this.rowHeight();
    this.box.scrollTop = Math.max(0, (line - 1) * height - this.box.clientHeight / 3);
    this.renderRows();
    this.box.focus({ preventScroll: true });
  }

  scrollToCurrent() {
    if (this.current <= 0 || this.current > this.lines.length) {
      return;
    }
    const height = this.rowHeight();
    const top = (this.current - 1) * height;
    const view = this.box.clientHeight;
    if (top < this.box.scrollTop || top + height > this.box.scrollTop + view) {
      // The line a third of the way down, so the lines coming next are in sight.
      this.box.scrollTop = Math.max(0, top - view / 3);
      this.renderRows();
    }
  }

  showProgress(program) {
    if (!program) {
      this.progress.value = 0;
      setText(this.progressText, 'no program open');
      setText(this.eta, '');
      return;
    }
    const total = program.lines_total || 0;
    this.progress.max = Math.max(total, 1);
    this.progress.value = program.lines_done || 0;
    setText(this.progressText, `${program.lines_done} / ${total} lines`);
    setText(this.eta, Number.isFinite(program.eta_s) && program.eta_s > 0
      ? `${duration(program.eta_s)} left` : '');
  }
}
