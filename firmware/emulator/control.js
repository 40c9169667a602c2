#!/usr/bin/env node
// Deterministic mode: one emulated device driven by JSON lines on stdin, one JSON reply line
// per request on stdout. See README.md for the protocol.
//
//   node control.js [--bootrom FILE]

import { createInterface } from 'node:readline';

import { parseArgs } from './lib/args.js';
import { DeviceError, EmulatedDevice } from './lib/emulated-device.js';
import { PIN_MAP, outputLevels, sweepEncoder } from './lib/pins.js';

const options = parseArgs(process.argv.slice(2), ['bootrom']);
let device = null;
let powered = false;
let spanStart = null;

function bytesToText(bytes) {
  return Buffer.from(bytes).toString('latin1');
}

function requireDevice() {
  if (!device) {
    throw new DeviceError('no firmware loaded: send {"cmd": "load", ...} first');
  }
  if (!powered) {
    throw new DeviceError('device is off: send {"cmd": "power_up"} first');
  }
  return device;
}

function span() {
  const now = { cycles: device.busyCycles(), nanos: device.nanos };
  const result = {
    tick: device.ticksDone(),
    cycles: [now.cycles[0] - spanStart.cycles[0], now.cycles[1] - spanStart.cycles[1]],
    emulated_ns: now.nanos - spanStart.nanos,
    output: device.takeOutput().map(({ tick, bytes }) => [tick, bytesToText(bytes)]),
  };
  spanStart = now;
  return result;
}

function powerUp(request) {
  if (request.erase_flash) {
    device.flash.resetData();
  }
  const wallStart = performance.now();
  device.bootHeld();
  powered = true;
  spanStart = { cycles: [0, 0], nanos: 0 };
  const result = span();
  result.wall_ms = performance.now() - wallStart;
  return result;
}

const commands = {
  load(request) {
    for (const key of ['uf2']) {
      if (typeof request[key] !== 'string') {
        throw new DeviceError(`load needs "${key}": a file path`);
      }
    }
    device = new EmulatedDevice({
      uf2: request.uf2,
      elf: request.elf,
      flash: request.flash ?? null,
      bootrom: options.bootrom,
    });
    powered = false;
    const symbols = {};
    for (const name of request.symbols ?? []) {
      const symbol = device.symbols.get(name);
      symbols[name] = symbol ? symbol.address : null;
    }
    return { symbols };
  },
  power_up: (request) => {
    if (!device) {
      throw new DeviceError('no firmware loaded: send {"cmd": "load", ...} first');
    }
    return powerUp(request);
  },
  power_cycle: (request) => {
    requireDevice();
    return powerUp(request);
  },
  power_down() {
    requireDevice();
    powered = false;
    device.mcu = null;
    return {};
  },
  flash_reset() {
    if (!device) {
      throw new DeviceError('no firmware loaded');
    }
    device.flash.resetData();
    return {};
  },
  feed(request) {
    const d = requireDevice();
    if (typeof request.data !== 'string') {
      throw new DeviceError('feed needs "data": the bytes as a string of code points 0-255');
    }
    const bytes = Buffer.from(request.data, 'latin1');
    d.feed(bytes);
    return span();
  },
  run(request) {
    const d = requireDevice();
    const ticks = request.ticks;
    if (!Number.isInteger(ticks) || ticks < 0) {
      throw new DeviceError(`run needs "ticks": a whole number >= 0, not ${JSON.stringify(ticks)}`);
    }
    d.runTicks(ticks);
    return span();
  },
  status() {
    const d = requireDevice();
    return { tick: d.ticksDone(), busy_cycles: d.busyCycles(), emulated_ns: d.nanos, timer_held: d.timerHeld };
  },
  profile(request) {
    const d = requireDevice();
    if (request.on) {
      d.startProfile();
      return {};
    }
    return { functions: d.stopProfile() };
  },
  boot_reply(request) {
    if (!device) {
      throw new DeviceError('no firmware loaded: send {"cmd": "load", ...} first');
    }
    const result = device.bootToFirstReply(Buffer.from(request.data ?? '2 -1\n', 'latin1'));
    powered = true;
    spanStart = { cycles: device.busyCycles(), nanos: device.nanos };
    return {
      usb_enabled_ns: result.usbEnabledNs,
      configured_ns: result.configuredNs,
      reply_ns: result.replyNs,
      cycles: result.cycles,
    };
  },
  stacks() {
    const d = requireDevice();
    return { stacks: d.stackUsage() };
  },
  read(request) {
    const d = requireDevice();
    const symbol = d.symbols.get(request.symbol);
    if (!symbol) {
      throw new DeviceError(`no symbol ${JSON.stringify(request.symbol)} in the ELF`);
    }
    const size = request.size ?? symbol.size;
    const bytes = new Uint8Array(size);
    for (let i = 0; i < size; i++) {
      bytes[i] = d.mcu.readUint8(symbol.address + i);
    }
    return { address: symbol.address, hex: Buffer.from(bytes).toString('hex') };
  },
  write(request) {
    const d = requireDevice();
    const symbol = d.symbols.get(request.symbol);
    if (!symbol) {
      throw new DeviceError(`no symbol ${JSON.stringify(request.symbol)} in the ELF`);
    }
    const offset = request.offset ?? 0;
    const bytes = Buffer.from(request.hex ?? '', 'hex');
    if (!Number.isInteger(offset) || offset < 0 || offset + bytes.length > symbol.size) {
      throw new DeviceError(`write of ${bytes.length} bytes at ${JSON.stringify(offset)} is outside`
        + ` ${request.symbol} (${symbol.size} bytes)`);
    }
    for (let i = 0; i < bytes.length; i++) {
      d.mcu.writeUint8(symbol.address + offset + i, bytes[i]);
    }
    return { address: symbol.address };
  },
  levels(request) {
    const d = requireDevice();
    const { pins } = request;
    if (!Array.isArray(pins) || !pins.every((pin) => Number.isInteger(pin) && pin >= 0 && pin < 30)) {
      throw new DeviceError(`levels "pins" must list GPIO numbers 0-29, not ${JSON.stringify(pins)}`);
    }
    d.pins.catchUp(d.nanos);
    return { levels: pins.map((pin) => {
      const gpio = d.mcu.gpio[pin];
      return gpio.outputEnable ? Number(gpio.outputValue) : null;
    }) };
  },
  motor(request) {
    const d = requireDevice();
    const world = d.attachMotor(request.options ?? {});
    return { world: world.state };
  },
  stepper(request) {
    const d = requireDevice();
    const world = d.attachStepper(request.options ?? {});
    return { world: world.state };
  },
  encoder_pwm(request) {
    const d = requireDevice();
    const pwm = d.world ? d.world.pwm : null;
    if (!pwm) {
      throw new DeviceError('no absolute encoder: attach a motor or stepper with "absolute" options first');
    }
    if (typeof request.on !== 'boolean') {
      throw new DeviceError(`encoder_pwm needs "on": true or false, not ${JSON.stringify(request.on)}`);
    }
    d.pins.catchUp(d.nanos);
    if (request.on) {
      pwm.resume();
    } else {
      pwm.silence();
    }
    return { pwm: pwm.state };
  },
  world() {
    const d = requireDevice();
    if (!d.world) {
      throw new DeviceError('no motor attached: send {"cmd": "motor", "options": {...}} first');
    }
    return { world: d.world.state, pins: pinLevels(d) };
  },
  outputs() {
    const d = requireDevice();
    return { levels: outputLevels(d.mcu) };
  },
  sweep(request) {
    const d = requireDevice();
    const { counts, counts_per_s: countsPerS, skip = [] } = request;
    if (!Number.isInteger(counts) || counts === 0) {
      throw new DeviceError(`sweep needs "counts": a whole number other than 0, not ${JSON.stringify(counts)}`);
    }
    if (typeof countsPerS !== 'number' || !(countsPerS > 0) || countsPerS > 62.5e6) {
      throw new DeviceError(`sweep needs "counts_per_s" within 0..62,500,000 (two clock cycles), not ${JSON.stringify(countsPerS)}`);
    }
    if (!Array.isArray(skip) || !skip.every((k) => Number.isInteger(k) && k >= 1)) {
      throw new DeviceError(`sweep "skip" must list counts numbered from 1, not ${JSON.stringify(skip)}`);
    }
    const startNanos = d.nanos + 2e3;
    const endNanos = sweepEncoder(d.pins, {
      startNanos, counts, countsPerS, startCount: sweepState.count, skip,
    });
    sweepState.count += counts;
    d.releaseTimer();
    d.advance(endNanos + 2e3);
    d.settle();
    return { ...span(), start_ns: startNanos, end_ns: endNanos };
  },
  capture(request) {
    const d = requireDevice();
    const { pins } = request;
    const taken = d.pins.takeCapture();
    if (pins !== undefined) {
      if (!Array.isArray(pins) || !pins.every((pin) => Number.isInteger(pin) && pin >= 0 && pin < 30)) {
        throw new DeviceError(`capture "pins" must list GPIO numbers 0-29, not ${JSON.stringify(pins)}`);
      }
      d.pins.startCapture(pins);
    }
    return { edges: taken.edges, flags: taken.flags };
  },
  quit() {
    return {};
  },
};

/** Where the encoder pins were left by the sweeps (a count; power-up keeps them). */
const sweepState = { count: 0 };

function pinLevels(d) {
  const levels = {};
  for (const [name, pin] of Object.entries(PIN_MAP)) {
    const gpio = d.mcu.gpio[pin];
    levels[name] = gpio.outputEnable ? gpio.outputValue : gpio.inputValue;
  }
  return levels;
}

const lines = createInterface({ input: process.stdin, crlfDelay: Infinity });
for await (const line of lines) {
  if (!line.trim()) {
    continue;
  }
  let request;
  let reply;
  try {
    request = JSON.parse(line);
    const handler = Object.hasOwn(commands, request.cmd) ? commands[request.cmd] : null;
    if (!handler) {
      throw new DeviceError(`unknown cmd ${JSON.stringify(request.cmd)}; known: ${Object.keys(commands).join(', ')}`);
    }
    reply = { ok: true, ...handler(request) };
  } catch (error) {
    reply = { ok: false, error: error instanceof SyntaxError ? `bad JSON: ${error.message}` : error.message };
  }
  if (request && request.id !== undefined) {
    reply.id = request.id;
  }
  process.stdout.write(`${JSON.stringify(reply)}\n`);
  if (request && request.cmd === 'quit') {
    break;
  }
}
