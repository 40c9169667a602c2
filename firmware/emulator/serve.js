#!/usr/bin/env node
// Real-time mode: one emulated device whose USB CDC port is served on a TCP port, emulated
// time paced to the wall clock (never faster; when the emulator cannot keep up it runs as
// fast as it can and says so once on stderr). One client at a time; the next connection is
// taken when the current one closes. Device output with no client connected is dropped, as a
// port nobody reads.
//
//   node serve.js --uf2 FILE [--elf FILE] [--flash FILE] [--tcp PORT] [--host ADDR] [--bootrom FILE]
//                 [--exit-with-stdin 1]
//
// Prints "listening ADDR:PORT" on stdout once it accepts connections (PORT 0: any free port).
// With --exit-with-stdin 1 it exits when its standard input closes: a parent process that
// holds the pipe takes the emulator with it, however it ends.

import { createServer } from 'node:net';

import { parseArgs } from './lib/args.js';
import { EmulatedDevice } from './lib/emulated-device.js';

/** Emulated time run between two looks at the sockets and the wall clock. */
const CHUNK_NS = 1e6;
/** Lag behind the wall clock that counts as not keeping up. */
const LAG_LIMIT_MS = 250;
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
]);
if (!options.uf2) {
  process.stderr.write('serve.js: --uf2 FILE is required\n');
  process.exit(2);
}
const port = Number(options.tcp ?? 0);
const host = options.host ?? '127.0.0.1';

const device = new EmulatedDevice({
  uf2: options.uf2,
  elf: options.elf,
  flash: options.flash ?? null,
  bootrom: options.bootrom,
});
device.powerUp();

let client = null;
const waiting = [];

device.onOutput = (data) => {
  if (client) {
    client.write(Buffer.from(data));
  }
};

function take(socket) {
  client = socket;
  socket.setNoDelay(true);
  socket.on('data', (data) => {
    device.send(data);
    if (device.host.queuedBytes > INPUT_HIGH_WATER) {
      socket.pause();
    }
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
let warned = false;

function step() {
  try {
    device.advance(device.nanos + CHUNK_NS);
  } catch (error) {
    process.stderr.write(`serve.js: device stopped: ${error.message}\n`);
    process.exit(1);
  }
  if (client && client.isPaused() && device.host.queuedBytes < INPUT_HIGH_WATER / 2) {
    client.resume();
  }
  const aheadMs = (device.nanos - emulatedBase) / 1e6 - (performance.now() - wallBase);
  if (aheadMs > 0) {
    setTimeout(step, aheadMs);
    return;
  }
  if (-aheadMs > LAG_LIMIT_MS) {
    if (!warned) {
      warned = true;
      process.stderr.write(
        'serve.js: the emulator cannot keep up with real time here; running as fast as it can\n',
      );
    }
    // start counting again from now: never run faster than real time to make up for it
    wallBase = performance.now();
    emulatedBase = device.nanos;
  }
  setImmediate(step);
}

server.listen(port, host, () => {
  const address = server.address();
  process.stdout.write(`listening ${address.address}:${address.port}\n`);
  wallBase = performance.now();
  emulatedBase = device.nanos;
  step();
});

if (options['exit-with-stdin'] === '1') {
  process.stdin.on('end', () => process.exit(0));
  process.stdin.on('error', () => process.exit(0));
  process.stdin.resume();
}

for (const signal of ['SIGINT', 'SIGTERM']) {
  process.on(signal, () => {
    server.close();
    process.exit(0);
  });
}
