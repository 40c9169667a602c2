// Drives cncjs's web page in headless Chromium (the system's browser, through
// playwright-core): choose the port in the Connection widget and open it, unlock, upload a
// program and run it, then read the Axes widget's machine position. Prints one JSON line.
//
// usage: node cncjs_page.js CNCJS_URL PORT_PATH PROGRAM_FILE SCREENSHOT_FILE CHROMIUM
// environment: DRO_EXPECTED, the machine position to wait for (a JSON list of the shown
// texts); DRO_TOLERANCE_MM, how far each shown number may be from it (else the texts
// equal); HOMING=1, home (the Grbl widget's Homing button) after unlocking
'use strict';

const { chromium } = require('playwright-core');

const [url, portPath, programFile, screenshot, executablePath] = process.argv.slice(2);
const STEP_TIMEOUT_MS = 20000;

async function main() {
  const browser = await chromium.launch({ executablePath, args: ['--no-sandbox'] });
  try {
    const page = await browser.newPage({ viewport: { width: 1400, height: 1000 } });
    page.setDefaultTimeout(STEP_TIMEOUT_MS);
    await page.goto(url, { waitUntil: 'load' });

    // The Connection widget comes first: its port list is the page's first select.
    await page.waitForFunction(() => {
      const select = document.querySelector('.Select');
      return select && !select.classList.contains('is-disabled');
    }, null, { timeout: STEP_TIMEOUT_MS });
    await page.locator('.Select .Select-control').first().click();
    await page.locator('.Select-option', { hasText: portPath }).first().click();
    await page.locator('button:has-text("Open")').first().click();
    await page.locator('button:has-text("Close")').first().waitFor();

    await page.getByTitle('Unlock').click();
    if (process.env.HOMING === '1') {
      await page.getByTitle('Homing', { exact: true }).click();
    }
    const machinePosition = () => page.$$eval('td[class*="machine-position"]',
      (cells) => cells.map((cell) => cell.innerText.split('\n')[0].trim()));

    await page.locator('input[type="file"]').first().setInputFiles(programFile);
    const run = page.getByTitle('Run');
    await page.waitForFunction(() => {
      const button = document.querySelector('[title="Run"]');
      return button && !button.disabled;
    }, null, { timeout: STEP_TIMEOUT_MS });
    await run.click();
    const wanted = JSON.parse(process.env.DRO_EXPECTED || 'null');
    const tolerance = process.env.DRO_TOLERANCE_MM;
    const shows = (texts) => (tolerance === undefined
      ? JSON.stringify(texts) === JSON.stringify(wanted)
      : texts.length === wanted.length && texts.every(
        (text, index) => Math.abs(Number(text) - Number(wanted[index])) <= Number(tolerance)));
    const deadline = Date.now() + STEP_TIMEOUT_MS;
    let shown = await machinePosition();
    while (wanted && !shows(shown) && Date.now() < deadline) {
      await page.waitForTimeout(100);
      shown = await machinePosition();
    }
    await page.screenshot({ path: screenshot });
    process.stdout.write(`${JSON.stringify({ machinePosition: shown })}\n`);
  } finally {
    await browser.close();
  }
}

main().then(() => process.exit(0), (error) => {
  process.stderr.write(`${error.stack || error}\n`);
  process.exit(1);
});
