// The browser side of benchmarks/dashboard.py: opens the dashboard in headless Chromium,
// and for every state the page's WebSocket receives, notes when the frame after it was
// painted while the machine runs a program (the first requestAnimationFrame after the
// message: the page updates its DRO and
// charts in the message's own task, so that frame shows them): the paint's wall time less
// the message's sent_s, plus its age_s (how old the live model's picture was when sent), in
// a buffer allocated once (the page's heap is measured too). Keeps the page open until
// standard input closes, then prints one JSON line: those latencies (s), the number of
// states received, the page's JS heap at the start and the end.
//
// usage: node _dashboard_page.js URL_WITH_TOKEN CHROMIUM
'use strict';

const path = require('path');
const { chromium } = require(path.join(__dirname, '..', 'tests', 'senders', 'node_modules',
  'playwright-core'));

const [url, executablePath] = process.argv.slice(2);

async function heap(page) {
  return page.evaluate(() => (performance.memory ? performance.memory.usedJSHeapSize : null));
}

async function main() {
  const browser = await chromium.launch({
    executablePath,
    args: ['--no-sandbox', '--disable-gpu', '--disable-background-networking',
      '--disable-component-update', '--no-first-run', '--enable-precise-memory-info'],
  });
  try {
    const page = await browser.newPage({ viewport: { width: 1400, height: 900 } });
    await page.addInitScript(() => {
      const seen = { count: 0, latency: new Float64Array(200000) };
      window.benchmarkSeen = seen;
      const Native = window.WebSocket;
      window.WebSocket = class extends Native {
        constructor(...args) {
          super(...args);
          this.addEventListener('message', (event) => {
            let data;
            try { data = JSON.parse(event.data); } catch (error) { return; }
            if (data.type !== 'state' || data.state !== 'Run') return;
            requestAnimationFrame(() => {
              const painted = (performance.timeOrigin + performance.now()) / 1000;
              seen.latency[seen.count % seen.latency.length] = painted - data.sent_s + data.age_s;
              seen.count += 1;
            });
          });
        }
      };
    });
    await page.goto(url, { waitUntil: 'load' });
    await page.waitForFunction(() => window.benchmarkSeen.count > 10, null, { timeout: 30000 });
    const heapStart = await heap(page);
    process.stdout.write('ready\n');
    await new Promise((resolve) => {
      process.stdin.on('end', resolve);
      process.stdin.resume();
    });
    const seen = await page.evaluate(() => ({
      count: window.benchmarkSeen.count,
      latency: Array.from(window.benchmarkSeen.latency.subarray(
        0, Math.min(window.benchmarkSeen.count, window.benchmarkSeen.latency.length))),
    }));
    const heapEnd = await heap(page);
    process.stdout.write(`${JSON.stringify({ ...seen, heapStart, heapEnd })}\n`);
  } finally {
    await browser.close();
  }
}

main().catch((error) => {
  process.stderr.write(`${error.stack || error}\n`);
  process.exit(1);
});
