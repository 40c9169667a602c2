#!/usr/bin/env node
// Real-time mode: one emulated device whose USB CDC port is served on a TCP port, emulated
// time paced to the wall clock (never faster; when the emulator cannot keep up it runs as
// fast as it can and says so once on stderr). One client at a time; the next connection is
// taken when the current one closes. Device output with no client connected is dropped, as a
// port nobody reads.
//
//   node serve.js --uf2 FILE [--elf FILE] [--flash FILE] [--tcp PORT] [--host ADDR] [--bootrom FILE]
//                 [--exit-with-stdin 1] [--warm-up 0] [--record FILE] [--quantum CYCLES]
//
// Prints "listening ADDR:PORT" on stdout once it accepts connections (PORT 0: any free port).
// With --exit-with-stdin 1 it exits when its standard input closes: a parent process that
// holds the pipe takes the emulator with it, however it ends. Before serving, it runs a
// throwaway chip through a batch of setpoints so the JavaScript engine has compiled the
// emulator's hot paths (--warm-up 0 skips that), then boots the device until USB is
// configured. On exit it says on stderr how often it fell behind real time, if it did.
// --record FILE writes every chunk of bytes a client sends as a line `TICK HEX`, TICK the
// servo ticks done since power-up when it arrived: the session, for a deterministic replay.
// --quantum sets the cycles each core runs in turn when both are awake (default 256).

import { openSync, writeSync } from 'node:fs';
import { createServer } from 'node:net';

import { parseArgs } from './lib/args.js';
import { EmulatedDevice } from './lib/emulated-device.js';

/** Emulated time run at most between two looks at the sockets and the wall clock. */
const CHUNK_NS = 1e6;
/** How far a step may run ahead of the wall clock: input is answered without waiting for
 * the next timer, and the emulated clock still never gains on the wall clock. */
const LEAD_NS = 0.2e6;
/** Lag behind the wall clock that counts as not keeping up. */
const LAG_LIMIT_MS = 250;
/** Cycles a core runs before the other gets its turn when both are awake: a quarter of
 * the emulator's work per emulated second is switching at the deterministic mode's 64
 * (2.3 s against 1.4 s of wall time for 5 s of a streaming device); 2 us slices here. */
const REALTIME_QUANTUM_CYCLES = 256;
/** Emulated time a device may take to configure USB at power-up. */
const BOOT_LIMIT_NS = 1e9;
/** Input held for the device before the client's socket is paused. */
const INPUT_HIGH_WATER = 64 * 1024;

const options = parseArgs(process.argv.slice(2), [
  'uf2',
  'elf',
  'flash',
  'tcp',
  'host',
  'bootrom',
  'exit-with-stdin',
  'warm-up',
  'record',
  'quantum',
]);
if (!options.uf2) {
  process.stderr.write('serve.js: --uf2 FILE is required\n');
  process.exit(2);
}
const port = Number(options.tcp ?? 0);
const host = options.host ?? '127.0.0.1';

/**
 * Runs a throwaway chip (no flash file) through what a host makes a device do, a batch of
 * setpoints with diagnostics lines, so the JavaScript engine has compiled the emulator's hot
 * paths before real time starts: the first such batch otherwise takes ten times as long.
 */
function warmUp() {
  const scratch = new EmulatedDevice({ uf2: options.uf2, elf: options.elf, bootrom: options.bootrom });
  scratch.bootHeld();
  const values = Array.from({ length: 600 }, (_, i) => String((i * 7919) % 200001 - 100000));
  scratch.feed(Buffer.from(`8 1 2\n21 5\n3 1\n1 600 ${values.join(' ')}\n2 -1\n20 -1\n`));
  scratch.runTicks(100);
  scratch.feed(Buffer.from(`1 600 ${values.join(' ')}\n2 -1\n3 0\n`));
}

if (options['warm-up'] !== '0') {
  warmUp();
}
const device = new EmulatedDevice({
  uf2: options.uf2,
  elf: options.elf,
  flash: options.flash ?? null,
  bootrom: options.bootrom,
  quantumCycles: Number(options.quantum ?? REALTIME_QUANTUM_CYCLES),
});
device.powerUp();
// boot until USB is configured before serving, so real time starts at a running device
for (let waited = 0; !device.host.connected && waited < BOOT_LIMIT_NS; waited += CHUNK_NS) {
  device.advance(device.nanos + CHUNK_NS);
}

let client = null;
const waiting = [];

device.onOutput = (data) => {
  if (client) {
    client.write(Buffer.from(data));
  }
};

const record = options.record ? openSync(options.record, 'w') : null;

function take(socket) {
  client = socket;
  socket.setNoDelay(true);
  socket.on('data', (data) => {
    if (record !== null) {
      writeSync(record, `${device.ticksDone()} ${data.toString('hex')}\n`);
    }
    device.send(data);
    if (device.host.queuedBytes > INPUT_HIGH_WATER) {
      socket.pause();
    }
    wake();
  });
  socket.resume();
}

function release(socket) {
  const index = waiting.indexOf(socket);
  if (index >= 0) {
    waiting.splice(index, 1);
  }
  if (client === socket) {
    client = null;
    const next = waiting.shift();
    if (next) {
      take(next);
    }
  }
}

const server = createServer({ pauseOnConnect: true }, (socket) => {
  socket.on('close', () => release(socket));
  socket.on('error', () => release(socket));
  if (client) {
    waiting.push(socket);
  } else {
    take(socket);
  }
});

let wallBase = 0;
let emulatedBase = 0;
let lags = 0; // times the emulator fell more than LAG_LIMIT_MS behind and started again
let worstLagMs = 0;
let lostMs = 0;
let timer = null; // the pending wake-up, while the device is level with the wall clock
let stepping = false;

/** Emulated time the wall clock says it is now, plus the lead a step may run ahead. */
function wallNanos() {
  return emulatedBase + (performance.now() - wallBase) * 1e6;
}

/**
 * Runs the device up to the wall clock (and LEAD_NS beyond, so a reply to input that just
 * came goes out at once), at most CHUNK_NS at a time between looks at the sockets; then
 * sleeps until the next millisecond or until input comes, whichever is first.
 */
function step() {
  timer = null;
  stepping = true;
  try {
    const target = Math.min(wallNanos() + LEAD_NS, device.nanos + CHUNK_NS);
    if (target > device.nanos) {
      device.advance(target);
    }
  } catch (error) {
    process.stderr.write(`serve.js: device stopped: ${error.message}\n`);
    process.exit(1);
  } finally {
    stepping = false;
  }
  if (client && client.isPaused() && device.host.queuedBytes < INPUT_HIGH_WATER / 2) {
    client.resume();
  }
  const behindMs = (wallNanos() - device.nanos) / 1e6;
  if (behindMs <= 0) {
    timer = setTimeout(step, Math.max(1, -behindMs));
    return;
  }
  if (behindMs > LAG_LIMIT_MS) {
    if (lags === 0) {
      process.stderr.write(
        `serve.js: the emulator fell ${Math.round(behindMs)} ms behind real time ` +
          `${(device.nanos / 1e9).toFixed(3)} s after power-up; running as fast as it can\n`,
      );
    }
    lags++;
    worstLagMs = Math.max(worstLagMs, behindMs);
    lostMs += behindMs;
    // start counting again from now: never run faster than real time to make up for it
    wallBase = performance.now();
    emulatedBase = device.nanos;
  }
  setImmediate(step);
}

/** Input came: if the device sleeps level with the wall clock, let it take it now. */
function wake() {
  if (timer !== null && !stepping) {
    clearTimeout(timer);
    timer = null;
    setImmediate(step);
  }
}

server.listen(port, host, () => {
  const address = server.address();
  process.stdout.write(`listening ${address.address}:${address.port}\n`);
  wallBase = performance.now();
  emulatedBase = device.nanos;
  step();
});

/** Says on stderr how often the emulator fell behind real time, if it did, and exits. */
function exit() {
  if (lags > 0) {
    process.stderr.write(
      `serve.js: fell behind real time ${lags} times in ${(device.nanos / 1e9).toFixed(1)} s ` +
        `(worst ${Math.round(worstLagMs)} ms, ${Math.round(lostMs)} ms in all)\n`,
    );
  }
  process.exit(0);
}

if (options['exit-with-stdin'] === '1') {
  process.stdin.on('end', exit);
  process.stdin.on('error', exit);
  process.stdin.resume();
}

for (const signal of ['SIGINT', 'SIGTERM']) {
  process.on(signal, () => {
    server.close();
    exit();
  });
}
