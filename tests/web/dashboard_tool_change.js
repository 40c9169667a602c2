// Drives usbmotion web's dashboard in headless Chromium (playwright-core) through a
// program's tool change as an operator would: the program already runs and waits at its
// M6 pause; the page's Measure tool button (shown because the machine has a tool setter)
// is enabled there; clicking it measures the new tool and the program goes on to its end.
// Prints one JSON line: the messages the page listed, the state at the end, the console
// errors. Exits 1 with the failing step on stderr.
//
// usage: node dashboard_tool_change.js URL_WITH_TOKEN CHROMIUM
'use strict';

const { chromium } = require('../senders/node_modules/playwright-core');

const [url, executablePath] = process.argv.slice(2);
const STEP_TIMEOUT_MS = 60000;
const BROWSER_ARGS = ['--no-sandbox', '--disable-gpu', '--disable-background-networking',
  '--disable-component-update', '--no-first-run'];

async function main() {
  const consoleErrors = [];
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
    await page.goto(url, { waitUntil: 'load' });
    await page.locator('[data-testid="connection"]', { hasText: 'live' }).waitFor();
    await page.locator('[data-testid="state"]', { hasText: 'Paused' }).waitFor();
    const button = page.getByRole('button', { name: 'Measure tool', exact: true });
    await button.waitFor({ state: 'visible' });
    await page.waitForFunction((element) => !element.disabled, await button.elementHandle());
    await button.click();
    await page.locator('#log', { hasText: 'touched the setter' }).waitFor();
    await page.locator('#log', { hasText: 'completed' }).waitFor();
    await page.locator('[data-testid="state"]', { hasText: 'Idle' }).waitFor();
    const messages = await page.locator('#log li').allTextContents();
    const state = (await page.locator('[data-testid="state"]').textContent()).trim();
    process.stdout.write(`${JSON.stringify({ messages, state, console_errors: consoleErrors })}\n`);
  } finally {
    await browser.close();
  }
}

main().then(() => process.exit(0), (error) => {
  process.stderr.write(`${error.stack || error}\n`);
  process.exit(1);
});
