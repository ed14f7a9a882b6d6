// Drive the live viewer in headless Chromium: wait for the connected state and the first full
// resolution frame, then screenshot each requested output (chosen in the "Output" dropdown).
//
//   node tests/viewer/browser_check.mjs --url http://127.0.0.1:7007 --out DIR \
//        [--outputs clean,hazy,transmittance] [--width 960] [--height 640] [--hide-cameras]
//        [--second-page] [--reconnect] [--split hazy]
//   node tests/viewer/browser_check.mjs --url URL --out DIR --hold [--orbit]
//
// --split NAME: last, the first output with NAME right of the split line (DIR/split.png).
// --second-page: a second browser tab connects (while the first stays) and gets its own frame, then
// closes. --reconnect: at the end the first tab reloads (disconnect + connect) and waits for a frame.
// --hold (benchmarks): once a first frame is shown print "ready" and stay connected until stdin
// closes, with --orbit dragging the camera around all the while.
// Writes DIR/<output>.png (the whole page) and DIR/result.json (panel text before and after, so a
// test can check that training advanced while the browser watched). The Python test judges the
// pixels. playwright-core is looked up in $PLAYWRIGHT_CORE (a path), then .cache/node (see
// docs/viewer.md), then the usual Node resolution.

import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { createRequire } from 'node:module';
import { fileURLToPath } from 'node:url';

const here = path.dirname(fileURLToPath(import.meta.url));
const repo = path.resolve(here, '..', '..');

function loadPlaywright() {
  const require = createRequire(import.meta.url);
  const candidates = [
    process.env.PLAYWRIGHT_CORE,
    path.join(repo, '.cache', 'node', 'node_modules', 'playwright-core'),
    'playwright-core',
  ].filter(Boolean);
  for (const c of candidates) {
    try {
      return require(c);
    } catch {
      // try the next place
    }
  }
  throw new Error(`playwright-core not found (tried ${candidates.join(', ')})`);
}

function parseArgs(argv) {
  const args = { outputs: 'clean,hazy', width: 960, height: 640, timeout: 40000 };
  const flags = new Set(['hide-cameras', 'second-page', 'reconnect', 'hold', 'orbit']);
  for (let i = 0; i < argv.length; i++) {
    const key = argv[i].replace(/^--/, '');
    args[key] = flags.has(key) ? true : argv[++i];
  }
  if (!args.url || !args.out) throw new Error('usage: browser_check.mjs --url URL --out DIR [options]');
  return args;
}

const escape = (s) => s.replace(/[.*+?^${}()|[\]\\]/g, '\\$&');

async function panelText(page) {
  return page.evaluate(() => document.body.innerText);
}

/** Open the viewer in ``page`` and wait for a (full-resolution) frame of ``output``. */
async function connect(page, url, output, timeout, full = true) {
  await page.goto(url, { timeout });
  // connected: the viewer gives each browser a status line once its websocket is up
  await page.getByText(/^(connected · waiting|showing )/).first().waitFor({ timeout });
  // software WebGL (no GPU) brings up a notification over the canvas: keep it out of the shots
  await page.addStyleTag({ content: '.mantine-Notifications-root { display: none !important; }' });
  await shown(page, output, timeout, full);
}

async function shown(page, output, timeout, full = true) {
  const size = full ? ' · .* full' : ' · ';
  await page.getByText(new RegExp(`^showing ${escape(output)}${size}`)).waitFor({ timeout });
}

async function choose(page, label, option) {
  await page.getByLabel(label, { exact: true }).click();
  await page.getByRole('option', { name: option, exact: true }).click();
}

async function shoot(page, dir, name, result) {
  await page.waitForTimeout(700); // the frame arrived before its status line; let it be drawn
  const file = path.join(dir, `${name}.png`);
  await page.screenshot({ path: file });
  result.shots[name] = file;
}

/** Stay connected until stdin closes; with ``orbit`` keep dragging the camera (left button). */
async function hold(page, orbit) {
  let done = false;
  process.stdin.on('end', () => { done = true; });
  process.stdin.on('close', () => { done = true; });
  process.stdin.resume();
  console.log('ready');
  const viewport = page.viewportSize();
  const y = viewport.height * 0.6;
  while (!done) {
    if (!orbit) {
      await page.waitForTimeout(200);
      continue;
    }
    await page.mouse.move(viewport.width * 0.2, y);
    await page.mouse.down();
    for (let i = 1; i <= 20 && !done; i++) {
      await page.mouse.move(viewport.width * (0.2 + 0.015 * i), y, { steps: 2 });
      await page.waitForTimeout(40);
    }
    await page.mouse.up();
  }
}

async function main() {
  const args = parseArgs(process.argv.slice(2));
  const { chromium } = loadPlaywright();
  fs.mkdirSync(args.out, { recursive: true });
  const profile = fs.mkdtempSync(path.join(os.tmpdir(), 'td-viewer-chromium-'));
  const timeout = Number(args.timeout);
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: process.env.CHROMIUM || '/usr/bin/chromium',
    headless: true,
    viewport: { width: Number(args.width), height: Number(args.height) },
    args: [
      '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync',
    ],
  });
  const result = { console_errors: [], shots: {} };
  try {
    const page = await context.newPage();
    page.on('console', (m) => { if (m.type() === 'error') result.console_errors.push(m.text().slice(0, 300)); });
    page.on('pageerror', (e) => result.console_errors.push(String(e).slice(0, 300)));
    const outputs = args.outputs.split(',').filter(Boolean);
    await connect(page, args.url, outputs[0], timeout, !args.hold);
    result.text_before = await panelText(page);
    if (args.hold) {
      await hold(page, Boolean(args.orbit));
      return;
    }
    if (args['second-page']) {
      const other = await context.newPage();
      await connect(other, args.url, outputs[0], timeout);
      await other.close();
      result.second_page = true;
    }
    if (args['hide-cameras']) {
      await page.getByLabel('Training cameras').uncheck();
    }
    for (const [i, name] of outputs.entries()) {
      if (i > 0) {
        await choose(page, 'Output', name);
      }
      await shown(page, name, timeout);
      await shoot(page, args.out, name, result);
    }
    if (args.split) {
      await choose(page, 'Output', outputs[0]);
      await choose(page, 'Split with', args.split);
      await shown(page, `${outputs[0]} | ${args.split}`, timeout);
      await shoot(page, args.out, 'split', result);
    }
    if (args.reconnect) {
      await connect(page, args.url, outputs[0], timeout);
      result.reconnected = true;
    }
    result.text_after = await panelText(page);
  } finally {
    fs.writeFileSync(path.join(args.out, 'result.json'), JSON.stringify(result, null, 2));
    await context.close();
    fs.rmSync(profile, { recursive: true, force: true });
  }
}

main().catch((err) => {
  console.error(String(err && err.stack ? err.stack : err));
  process.exit(1);
});
