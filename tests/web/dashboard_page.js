// Drives usbmotion web's dashboard in headless Chromium (the system's browser, through
// playwright-core) as an operator would: home, open demo 1, predict it with a tolerance,
// run it with a hold and a resume to its end (then predicted beside measured), read the DRO
// beside the run's report, run it again and stop it, jog X+ by a step, send an MDI line,
// tune X automatically from the Tuning panel (with TUNE_AUTO=1 in the environment: the
// identification records every servo tick, which emulated chips behind real time cannot
// give), and read the DRO.
// Prints one JSON line: the DRO's machine positions as shown (at the end of the first run,
// with the report's and the API state's, and at the end), the program lines highlighted
// in the order first seen, what the prediction showed, the chart redraws a second while the program ran, the console
// errors and the steps done. Exits 1 with the failing step on stderr.
//
// usage: node dashboard_page.js URL_WITH_TOKEN SCREENSHOT_DIR CHROMIUM
'use strict';

const path = require('path');
const { chromium } = require('../senders/node_modules/playwright-core');

const [url, screenshotDir, executablePath] = process.argv.slice(2);
const STEP_TIMEOUT_MS = 30000;
const JOG_STEP_MM = 1;
const TOLERANCE_MM = 0.01;
const DRO_STEADY_MS = 1000;
const PREDICT_TOLERANCE_MM = 0.03;
const BROWSER_ARGS = ['--no-sandbox', '--disable-gpu', '--disable-background-networking',
  '--disable-component-update', '--no-first-run'];

const steps = [];
const consoleErrors = [];

async function step(name, action) {
  try {
    const result = await action();
    steps.push(name);
    return result;
  } catch (error) {
    error.message = `step ${JSON.stringify(name)} failed: ${error.message}`;
    throw error;
  }
}

// What the page shows of the machine, read from the document as a person reads it.
function shown(page) {
  return page.evaluate(() => {
    const text = (selector) => {
      const element = document.querySelector(selector);
      return element ? element.textContent.trim() : null;
    };
    const progress = /^(\d+) \/ (\d+) lines$/.exec(text('[data-testid="progress"]') || '');
    const dro = {};
    for (const cell of document.querySelectorAll('[data-testid$="-machine"]')) {
      dro[cell.dataset.testid.split('-')[1]] = cell.textContent.trim();
    }
    const work = {};
    for (const cell of document.querySelectorAll('[data-testid$="-work"]')) {
      work[cell.dataset.testid.split('-')[1]] = cell.textContent.trim();
    }
    return {
      state: text('[data-testid="state"]'),
      homed: text('[data-testid="homed"]') === 'homed',
      atRest: text('[data-testid="motion"]') === 'at rest',
      linesDone: progress ? Number(progress[1]) : null,
      linesTotal: progress ? Number(progress[2]) : null,
      dro,
      work,
    };
  });
}

// Polls what the page shows until `wanted` holds; fails after STEP_TIMEOUT_MS with the last
// thing seen.
async function waitFor(page, what, wanted) {
  const deadline = Date.now() + STEP_TIMEOUT_MS;
  let now = await shown(page);
  while (!wanted(now)) {
    if (Date.now() > deadline) {
      throw new Error(`waited ${STEP_TIMEOUT_MS / 1000} s for ${what}; the page shows ${JSON.stringify(now)}`);
    }
    await page.waitForTimeout(50);
    now = await shown(page);
  }
  return now;
}

async function click(page, name) {
  const button = page.getByRole('button', { name, exact: true }).first();
  await button.waitFor({ state: 'visible' });
  await page.waitForFunction((element) => !element.disabled, await button.elementHandle(),
    { timeout: STEP_TIMEOUT_MS });
  await button.click();
}

// Records, every animation frame, which program line is highlighted (aria-current).
function recordHighlights(page) {
  return page.evaluate(() => {
    const seen = [];
    window.dashboardTestHighlights = seen;
    const sample = () => {
      const current = document.querySelector('#program-text [aria-current="true"]');
      const line = current ? Number(current.dataset.line) : 0;
      if (line && seen[seen.length - 1] !== line) {
        seen.push(line);
      }
      if (window.dashboardTestHighlights === seen) {
        requestAnimationFrame(sample);
      }
    };
    requestAnimationFrame(sample);
  });
}

function stopRecordingHighlights(page) {
  return page.evaluate(() => {
    const seen = window.dashboardTestHighlights;
    window.dashboardTestHighlights = null;
    return seen;
  });
}

// The DRO's machine positions once they have shown the same figures for DRO_STEADY_MS.
async function steadyDro(page) {
  let last = JSON.stringify((await shown(page)).dro);
  let since = Date.now();
  await waitFor(page, `the DRO steady for ${DRO_STEADY_MS} ms`, (now) => {
    const texts = JSON.stringify(now.dro);
    if (texts !== last) {
      last = texts;
      since = Date.now();
    }
    return Date.now() - since >= DRO_STEADY_MS;
  });
  return JSON.parse(last);
}

// An API call with the page's token, as a script would make it.
async function api(apiPath) {
  const address = new URL(apiPath, url);
  address.searchParams.set('token', new URL(url).searchParams.get('token'));
  const answer = await fetch(address);
  if (!answer.ok) {
    throw new Error(`GET ${apiPath}: ${answer.status} ${await answer.text()}`);
  }
  return answer.json();
}

function median(values) {
  const sorted = [...values].sort((a, b) => a - b);
  const middle = sorted.length >> 1;
  return sorted.length % 2 ? sorted[middle] : (sorted[middle - 1] + sorted[middle]) / 2;
}

async function main() {
  const browser = await chromium.launch({ executablePath, args: BROWSER_ARGS });
  try {
    const page = await browser.newPage({ viewport: { width: 1400, height: 900 } });
    page.setDefaultTimeout(STEP_TIMEOUT_MS);
    page.on('console', (message) => {
      if (message.type() === 'error') {
        consoleErrors.push(message.text());
      }
    });
    page.on('pageerror', (error) => consoleErrors.push(`page error: ${error.message}`));

    await step('open the page', async () => {
      await page.goto(url, { waitUntil: 'load' });
      await page.locator('[data-testid="connection"]', { hasText: 'live' }).waitFor();
      await waitFor(page, 'the first state', (now) => now.state && now.state !== '—');
      if (new URL(page.url()).searchParams.has('token')) {
        throw new Error(`the token is still in the address bar: ${page.url()}`);
      }
    });

    await step('home', async () => {
      await click(page, 'Home');
      await waitFor(page, 'Idle, homed, at rest',
        (now) => now.state === 'Idle' && now.homed && now.atRest);
    });

    await step('open demo 1', async () => {
      await page.getByLabel('Program to open').selectOption('demo:1');
      await click(page, 'Open');
      await page.locator('#program-name', { hasText: '1-rounded-square.ngc' }).waitFor();
      await page.locator('#program-text .program-line').first().waitFor();
    });

    const predicted = await step('predict with a tolerance', async () => {
      await page.getByLabel('Tolerance (mm)', { exact: true }).fill(String(PREDICT_TOLERANCE_MM));
      await click(page, 'Predict');
      const summary = page.locator('[data-testid="over-tolerance"]');
      await summary.waitFor();
      const text = (await summary.textContent()).trim();
      const count = /^(\d+) lines? beyond /.exec(text);
      if (!count) {
        throw new Error(`the prediction names no lines beyond ${PREDICT_TOLERANCE_MM} mm: ${JSON.stringify(text)}`);
      }
      const listed = await page.getByRole('list', { name: `Lines beyond ${PREDICT_TOLERANCE_MM} mm` })
        .getByRole('button').allTextContents();
      const marked = await page.locator('#program-text .program-line.over-tolerance')
        .evaluateAll((rows) => rows.map((row) => Number(row.dataset.line)));
      const peaks = {};
      for (const row of await page.locator('[data-testid^="predicted-"]').all()) {
        const cells = await row.locator('td').allTextContents();
        peaks[(await row.getAttribute('data-testid')).split('-')[1]] = parseFloat(cells[0]);
      }
      await page.getByRole('button', { name: listed[listed.length - 1], exact: true }).click();
      return { tolerance_mm: PREDICT_TOLERANCE_MM, count: Number(count[1]),
        listed: listed.map((name) => Number(name.replace('Line ', ''))), marked, peaks_mm: peaks };
    });

    const chartWindow = {};
    await step('run with a hold to the end', async () => {
      await recordHighlights(page);
      await click(page, 'Run');
      await waitFor(page, 'Run', (now) => now.state === 'Run');
      chartWindow.startMs = await page.evaluate(() => performance.now());
      await page.waitForTimeout(1500);
      await click(page, 'Hold');
      await waitFor(page, 'Hold at rest', (now) => now.state === 'Hold' && now.atRest);
      await click(page, 'Resume');
      await waitFor(page, 'Run after the resume', (now) => now.state === 'Run');
      await page.waitForTimeout(1000);
      await page.screenshot({ path: path.join(screenshotDir, 'dashboard.png') });
      await waitFor(page, 'Idle with every line done', (now) => now.state === 'Idle'
        && now.linesTotal > 0 && now.linesDone === now.linesTotal);
      chartWindow.endMs = await page.evaluate(() => performance.now());
    });
    const highlighted = await stopRecordingHighlights(page);
    const redraws = await page.evaluate(() => window.usbmotionDashboard.chartUpdates);
    const perSecond = [];
    for (let second = chartWindow.startMs; second + 1000 <= chartWindow.endMs; second += 1000) {
      perSecond.push(redraws.filter((time) => time >= second && time < second + 1000).length);
    }

    const runEnd = await step('the DRO beside the run report', async () => {
      const dro = await steadyDro(page);
      const report = await api('/api/report');
      const state = await api('/api/state');
      const machine = {};
      for (const [axis, figures] of Object.entries(state.axes)) {
        machine[axis] = figures.machine_mm;
      }
      // The run of the predicted program: predicted beside measured, per axis.
      await page.locator('[data-testid="compared-X"]').waitFor();
      const compared = {};
      for (const row of await page.locator('[data-testid^="compared-"]').all()) {
        const cells = await row.locator('td').allTextContents();
        compared[(await row.getAttribute('data-testid')).split('-')[1]] = cells.map(Number);
      }
      return { dro, report_end_mm: report.end_position_mm, completed: report.completed,
        state_machine_mm: machine, compared };
    });

    await step('run again and stop', async () => {
      await click(page, 'Run');
      await waitFor(page, 'Run', (now) => now.state === 'Run');
      await page.waitForTimeout(1000);
      await click(page, 'Stop');
      await waitFor(page, 'Idle at rest after the stop', (now) => now.state === 'Idle' && now.atRest);
      // The line it stopped at is offered to run from (not filled in: Run stays a whole run).
      const fromLine = page.getByLabel('From line', { exact: true });
      await page.waitForFunction((element) => /^stopped at \d+$/.test(element.placeholder),
        await fromLine.elementHandle(), { timeout: STEP_TIMEOUT_MS });
      if (await fromLine.inputValue() !== '') {
        throw new Error(`From line was filled in after the stop: ${await fromLine.inputValue()}`);
      }
    });

    await step('jog X+ by a step', async () => {
      await page.getByLabel('Step', { exact: true }).selectOption(String(JOG_STEP_MM));
      const before = Number((await shown(page)).dro.X);
      await click(page, 'Jog X+');
      await waitFor(page, `X at ${before + JOG_STEP_MM}`, (now) => now.state === 'Idle' && now.atRest
        && Math.abs(Number(now.dro.X) - before - JOG_STEP_MM) <= TOLERANCE_MM);
    });

    await step('MDI G0 X5 Y5', async () => {
      const mdi = page.getByLabel('MDI', { exact: true });
      await mdi.fill('G0 X5 Y5');
      await mdi.press('Enter');
      await waitFor(page, 'Idle at work X5 Y5', (now) => now.state === 'Idle' && now.atRest
        && Math.abs(Number(now.work.X) - 5) <= TOLERANCE_MM
        && Math.abs(Number(now.work.Y) - 5) <= TOLERANCE_MM);
    });

    const tuneAuto = process.env.TUNE_AUTO === '1';
    const tuned = !tuneAuto ? null : await step('tune X automatically', async () => {
      await page.locator('#tuning-panel > summary').click();
      await page.locator('#tune-axis').selectOption('X');
      await page.getByLabel('Travel (mm)', { exact: true }).fill('20');
      await click(page, 'Identify and place gains');
      const result = page.getByTestId('auto-result');
      await result.getByRole('table').waitFor({ timeout: 60_000 });
      return {
        text: await result.innerText(),
        cells: await result.getByRole('cell').allTextContents(),
      };
    });

    const dro = await step('read the DRO', () => steadyDro(page));

    await step('phone layout', async () => {
      await page.setViewportSize({ width: 390, height: 844 });
      await page.waitForTimeout(500);
      const width = await page.evaluate(() => document.documentElement.scrollWidth);
      if (width > 390) {
        throw new Error(`the page is ${width} px wide on a 390 px screen: it scrolls sideways`);
      }
      await page.screenshot({ path: path.join(screenshotDir, 'dashboard-phone.png') });
    });

    process.stdout.write(`${JSON.stringify({
      dro,
      run_end: runEnd,
      predicted,
      tuned,
      highlighted,
      last_highlighted: highlighted[highlighted.length - 1],
      chart_updates_per_s: perSecond.length ? median(perSecond) : null,
      console_errors: consoleErrors,
      steps,
    })}\n`);
  } finally {
    await browser.close();
  }
}

main().then(() => process.exit(0), (error) => {
  process.stderr.write(`${error.stack || error}\n`);
  if (consoleErrors.length) {
    process.stderr.write(`console errors: ${JSON.stringify(consoleErrors)}\n`);
  }
  process.stderr.write(`steps done: ${JSON.stringify(steps)}\n`);
  process.exit(1);
});
