// Tests of the emulator harness itself, on the test fixture firmware (test/fixture), built by
// `make firmware` into build/firmware/usbmotion_fixture.uf2.

import assert from 'node:assert/strict';
import { spawn } from 'node:child_process';
import { existsSync, mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, join, resolve } from 'node:path';
import { createInterface } from 'node:readline';
import { after, before, describe, test } from 'node:test';
import { fileURLToPath } from 'node:url';

import { DualRP2040 } from '../lib/dual-core.js';
import { EmulatedDevice } from '../lib/emulated-device.js';
import { parseUf2 } from '../lib/uf2.js';

const here = dirname(fileURLToPath(import.meta.url));
const FIXTURE_UF2 =
  process.env.USBMOTION_FIXTURE_UF2 ?? resolve(here, '../../../build/firmware/usbmotion_fixture.uf2');

if (!existsSync(FIXTURE_UF2)) {
  throw new Error(`no fixture firmware at ${FIXTURE_UF2}: run \`make firmware\` first`);
}

const SIO = 0xd0000000;
const FIFO_ST = SIO + 0x50;
const FIFO_WR = SIO + 0x54;
const FIFO_RD = SIO + 0x58;

const text = (output) => output.map(({ tick, bytes }) => [tick, bytes.toString('latin1')]);
const joined = (output) => output.map(({ bytes }) => bytes.toString('latin1')).join('');

describe('SIO FIFOs', () => {
  test('a word written by core0 is read by core1, with status bits and the IRQ line', () => {
    const mcu = new DualRP2040();
    mcu.select(0);
    assert.equal(mcu.readUint32(SIO), 0, 'CPUID on core0');
    assert.equal(mcu.readUint32(FIFO_ST) & 0b11, 0b10, 'core0: empty, ready');
    mcu.writeUint32(FIFO_WR, 0xdeadbeef);
    assert.ok(mcu.cores[1].pendingInterrupts & (1 << 16), 'SIO_IRQ_PROC1 pending on core1');
    assert.equal(mcu.cores[0].pendingInterrupts & (1 << 15), 0, 'not on core0');
    mcu.select(1);
    assert.equal(mcu.readUint32(SIO), 1, 'CPUID on core1');
    assert.equal(mcu.readUint32(FIFO_ST) & 1, 1, 'core1: valid');
    assert.equal(mcu.readUint32(FIFO_RD), 0xdeadbeef);
    assert.equal(mcu.readUint32(FIFO_ST) & 1, 0);
    assert.equal(mcu.cores[1].pendingInterrupts & (1 << 16), 0, 'IRQ line low again');
    mcu.readUint32(FIFO_RD);
    assert.equal(mcu.readUint32(FIFO_ST) & 0b1000, 0b1000, 'ROE after reading empty');
    mcu.writeUint32(FIFO_ST, 0xff);
    assert.equal(mcu.readUint32(FIFO_ST) & 0b1100, 0, 'sticky flags cleared by a write');
  });

  test('eight words deep; a ninth sets WOF and is dropped', () => {
    const mcu = new DualRP2040();
    mcu.select(1);
    for (let i = 0; i < 8; i++) {
      mcu.writeUint32(FIFO_WR, i);
    }
    assert.equal(mcu.readUint32(FIFO_ST) & 0b10, 0, 'core1 not ready: core0 FIFO full');
    mcu.writeUint32(FIFO_WR, 99);
    assert.equal(mcu.readUint32(FIFO_ST) & 0b100, 0b100, 'WOF');
    mcu.select(0);
    const words = Array.from({ length: 8 }, () => mcu.readUint32(FIFO_RD));
    assert.deepEqual(words, [0, 1, 2, 3, 4, 5, 6, 7]);
  });

  test('the hardware divider is per core', () => {
    const mcu = new DualRP2040();
    mcu.select(0);
    mcu.writeUint32(SIO + 0x60, 100); // unsigned dividend
    mcu.writeUint32(SIO + 0x64, 7); // unsigned divisor
    mcu.select(1);
    mcu.writeUint32(SIO + 0x60, 9);
    mcu.writeUint32(SIO + 0x64, 2);
    // (the package leaves the quotient unrounded; a load into a register truncates it)
    mcu.select(0);
    assert.equal(mcu.readUint32(SIO + 0x70) >>> 0, 14);
    mcu.select(1);
    assert.equal(mcu.readUint32(SIO + 0x70) >>> 0, 4);
  });
});

describe('UF2 loader', () => {
  test('rejects a file that is not UF2', () => {
    assert.throws(() => parseUf2(new Uint8Array(512)), /bad magic/);
    assert.throws(() => parseUf2(new Uint8Array(100)), /512-byte blocks/);
  });
});

describe('fixture firmware, deterministic', () => {
  let folder;
  let device;
  before(() => {
    folder = mkdtempSync(join(tmpdir(), 'usbmotion-emulator-'));
    device = new EmulatedDevice({ uf2: FIXTURE_UF2, flash: join(folder, 'flash.bin') });
    device.bootHeld();
  });
  after(() => rmSync(folder, { recursive: true, force: true }));

  test('both cores run: core1 was launched through the FIFOs and ticks', () => {
    assert.equal(device.ticksDone(), 0, 'tick 0 at power-up');
    device.runTicks(3);
    assert.equal(device.ticksDone(), 3);
    const [busy0, busy1] = device.busyCycles();
    assert.ok(busy0 > 0 && busy1 > 0, `both cores executed: ${busy0}, ${busy1}`);
  });

  test('CDC round trip, and input injected at a given tick', () => {
    device.takeOutput();
    device.feed(Buffer.from('hello\n'));
    assert.deepEqual(text(device.takeOutput()), [[3, '5 3\n']]);
    device.runTicks(37);
    device.feed(Buffer.from('ab'));
    device.feed(Buffer.from('c\n'));
    assert.deepEqual(text(device.takeOutput()), [[40, '3 40\n']]);
  });

  test('many lines in one feed are all answered at that tick', () => {
    const lines = Array.from({ length: 300 }, (_, i) => `${'x'.repeat(i % 50)}\n`).join('');
    device.feed(Buffer.from(lines));
    const output = device.takeOutput();
    assert.equal(output.length, 1);
    const tick = device.ticksDone();
    const expected = Array.from({ length: 300 }, (_, i) => `${i % 50} ${tick}\n`).join('');
    assert.equal(output[0].bytes.toString(), expected);
  });

  test('records written by core1 are printed by core0, stamped with their tick', () => {
    const start = device.ticksDone();
    device.feed(Buffer.from('d 3\n'));
    device.runTicks(5);
    assert.deepEqual(text(device.takeOutput()), [
      [start, 'd\n'],
      [start + 1, `t ${start + 1}\n`],
      [start + 2, `t ${start + 2}\n`],
      [start + 3, `t ${start + 3}\n`],
    ]);
  });

  test('queue_t across cores: core0 adds, each tick on core1 takes one', () => {
    device.takeOutput();
    device.feed(Buffer.from('q 1 2 3 4 5 6 7\n'));
    device.runTicks(4);
    device.feed(Buffer.from('s\n'));
    device.runTicks(10);
    device.feed(Buffer.from('s\n'));
    assert.equal(joined(device.takeOutput()), 'q 7\ns 10 3\ns 28 0\n');
  });

  test('the servo period: ticks at 500 us after call p 500', () => {
    device.feed(Buffer.from('p 500\n'));
    const before = device.timerNanos;
    device.runTicks(100);
    const perTickUs = (device.timerNanos - before) / 100 / 1000;
    assert.ok(Math.abs(perTickUs - 500) < 5, `${perTickUs} us per tick`);
    device.feed(Buffer.from('p 1000\n'));
    device.takeOutput();
  });

  test('at 10 kHz every record reaches the host at its tick: SOFs end the E15 deferral', () => {
    // TinyUSB holds back a bulk IN transfer started 800-998 us after the last SOF until the
    // next one (erratum RP2040-E15): without the host's SOFs the port would stop for good.
    // Fresh from power-up, the timer passes 800-998 us after boot's last SOF within ten ticks.
    const fresh = new EmulatedDevice({ uf2: FIXTURE_UF2 });
    fresh.bootHeld();
    fresh.feed(Buffer.from('p 100\nd 40\n'));
    fresh.runTicks(40);
    const output = text(fresh.takeOutput());
    assert.deepEqual(output.slice(0, 1), [[0, 'p 100\nd\n']]);
    assert.deepEqual(output.slice(1), Array.from({ length: 40 }, (_, i) => [i + 1, `t ${i + 1}\n`]));
  });

  test('a tick longer than the servo period: the next one is not run early to catch up', () => {
    const fresh = new EmulatedDevice({ uf2: FIXTURE_UF2 });
    fresh.bootHeld();
    fresh.feed(Buffer.from('p 100\nk 20000\n')); // about 10 periods of spinning
    const before = fresh.busyCycles()[1];
    fresh.runTicks(1);
    assert.equal(fresh.ticksDone(), 1);
    assert.ok(fresh.busyCycles()[1] - before > 100000, 'the long tick ran');
    fresh.runTicks(3);
    assert.equal(fresh.ticksDone(), 4);
    fresh.feed(Buffer.from('x\n'));
    assert.deepEqual(text(fresh.takeOutput()).slice(-1), [[4, '1 4\n']]);
  });

  test('flash persists across a power cycle and a new emulator on the same file', () => {
    device.feed(Buffer.from('w 4242\nr\n'));
    assert.equal(joined(device.takeOutput()), 'w 1\nr 4242 1\n');
    device.bootHeld(); // power cycle
    device.feed(Buffer.from('r\n'));
    assert.deepEqual(text(device.takeOutput()), [[0, 'r 4242 2\n']]);
    const restarted = new EmulatedDevice({ uf2: FIXTURE_UF2, flash: join(folder, 'flash.bin') });
    restarted.bootHeld();
    restarted.feed(Buffer.from('r\n'));
    assert.deepEqual(text(restarted.takeOutput()), [[0, 'r 4242 3\n']]);
    restarted.flash.resetData();
    restarted.bootHeld();
    restarted.feed(Buffer.from('r\n'));
    assert.deepEqual(text(restarted.takeOutput()), [[0, 'r 0 1\n']], 'flash reset to the program');
  });

  test('the same session gives the same bytes, ticks and cycles', () => {
    const session = () => {
      const d = new EmulatedDevice({ uf2: FIXTURE_UF2, flash: null });
      d.bootHeld();
      d.feed(Buffer.from('d 2\nq 5 5\n'));
      d.runTicks(7);
      d.feed(Buffer.from('s\nr\n'));
      d.runTicks(1000);
      d.feed(Buffer.from('zz\n'));
      return { output: text(d.takeOutput()), cycles: d.busyCycles(), nanos: d.nanos };
    };
    assert.deepEqual(session(), session());
  });
});

describe('control.js', () => {
  test('JSON lines: load, power_up, feed, run, errors', async () => {
    const child = spawn(process.execPath, [resolve(here, '../control.js')], { stdio: ['pipe', 'pipe', 'inherit'] });
    const replies = createInterface({ input: child.stdout })[Symbol.asyncIterator]();
    const ask = async (request) => {
      child.stdin.write(`${JSON.stringify(request)}\n`);
      return JSON.parse((await replies.next()).value);
    };
    try {
      const loaded = await ask({ cmd: 'load', uf2: FIXTURE_UF2, symbols: ['usbmotion_ticks_done', 'nope'] });
      assert.equal(loaded.ok, true);
      assert.equal(typeof loaded.symbols.usbmotion_ticks_done, 'number');
      assert.equal(loaded.symbols.nope, null);
      assert.equal((await ask({ cmd: 'run', ticks: 1 })).ok, false, 'not powered yet');
      const boot = await ask({ cmd: 'power_up', erase_flash: true, id: 7 });
      assert.equal(boot.ok, true);
      assert.equal(boot.id, 7);
      assert.equal(boot.tick, 0);
      const run = await ask({ cmd: 'run', ticks: 25 });
      assert.equal(run.tick, 25);
      assert.ok(run.cycles[1] > 0);
      const fed = await ask({ cmd: 'feed', data: 'a\u00ff\n' });
      assert.deepEqual(fed.output, [[25, '2 25\n']]);
      assert.equal((await ask({ cmd: 'run', ticks: -1 })).ok, false);
      const unknown = await ask({ cmd: 'fly' });
      assert.match(unknown.error, /unknown cmd/);
      const cycled = await ask({ cmd: 'power_cycle' });
      assert.equal(cycled.tick, 0);
      await ask({ cmd: 'quit' });
    } finally {
      child.stdin.end();
    }
    const code = await new Promise((resolveExit) => child.on('exit', resolveExit));
    assert.equal(code, 0);
  });
});

describe('serve.js', () => {
  test('serves the CDC port on TCP in real time, one client at a time', async () => {
    const { connect } = await import('node:net');
    const child = spawn(process.execPath, [resolve(here, '../serve.js'), '--uf2', FIXTURE_UF2, '--tcp', '0'], {
      stdio: ['ignore', 'pipe', 'inherit'],
    });
    try {
      const lines = createInterface({ input: child.stdout })[Symbol.asyncIterator]();
      const listening = (await lines.next()).value;
      const match = /^listening 127\.0\.0\.1:(\d+)$/.exec(listening);
      assert.ok(match, listening);
      const port = Number(match[1]);
      const open = () =>
        new Promise((resolveOpen, reject) => {
          const socket = connect(port, '127.0.0.1', () => resolveOpen(socket));
          socket.on('error', reject);
        });
      const readLine = (socket) =>
        new Promise((resolveLine) => {
          let buffered = '';
          const onData = (data) => {
            buffered += data.toString('latin1');
            if (buffered.includes('\n')) {
              socket.off('data', onData);
              resolveLine(buffered);
            }
          };
          socket.on('data', onData);
        });
      const first = await open();
      const wallStart = performance.now();
      first.write('abcd\n');
      const reply = await readLine(first);
      assert.match(reply, /^4 \d+\n$/);
      const second = await open();
      const secondReply = readLine(second);
      second.write('xy\n');
      await new Promise((r) => setTimeout(r, 300));
      first.write('abc\n');
      const later = await readLine(first);
      const [, ticks] = later.trim().split(' ').map(Number);
      const [, ticksBefore] = reply.trim().split(' ').map(Number);
      const wallMs = performance.now() - wallStart;
      assert.ok(ticks - ticksBefore <= wallMs + 20, `never faster than real time: ${ticks - ticksBefore} ticks in ${wallMs} ms`);
      first.end();
      assert.match(await secondReply, /^2 \d+\n$/, 'the second client is served once the first leaves');
      second.end();
    } finally {
      child.kill('SIGTERM');
    }
  });
});
