// One emulated USB Motion Device: a dual-core RP2040 running a UF2 from its flash, with the
// USB host's end of the CDC port. Two ways to run it:
//   - runFor(ns): free running, as the chip does (serve.js paces it to the wall clock);
//   - runTicks(n) / feed(bytes): deterministic, at servo tick boundaries. The timer is held
//     (its count stops and its alarms wait, as when a debugger pauses it) while core0 takes in
//     and handles input, so input arrives between two ticks in no device time, and the tick
//     count (usbmotion_ticks_done, read by address from the ELF) says where each output byte
//     came.

import { readFileSync } from 'node:fs';

import { readBootrom, patchBootrom } from './bootrom.js';
import { CdcHost } from './cdc-host.js';
import { DualRP2040 } from './dual-core.js';
import { STT_FUNC, readElfSymbols } from './elf.js';
import { FLASH_BREAKPOINTS, FlashImage, answerFlashBreakpoint } from './flash.js';
import { MotorWorld, PioClock, StepperWorld } from './pins.js';
import { parseUf2 } from './uf2.js';

const SRAM_BASE = 0x20000000;
const TIMER_KEY = 0x40054;
const TICKS_SYMBOL = 'usbmotion_ticks_done';
/** Each core's stack, by the linker script's symbols: [bottom, top]. */
const STACK_SYMBOLS = [
  ['__StackBottom', '__StackTop'],
  ['__StackOneBottom', '__StackOneTop'],
];
/** What a stack is painted with at power-up: the bytes still holding it were never used. */
const STACK_PAINT = 0x5a;
/** Cycles a core runs before the other gets its turn, when both are awake. */
export const QUANTUM_BOTH_CYCLES = 64;
/** ... and when the other sleeps (it wakes at the next quantum at the latest). */
export const QUANTUM_ONE_CYCLES = 1024;
/** The longest slice of emulated time the motor outside the chip holds its voltage for. */
export const WORLD_SLICE_NS = 5e3;
/** Emulated time a device may take to finish handling input before it counts as hung. */
const SETTLE_LIMIT_NS = 10e9;

export class DeviceError extends Error {}

export class EmulatedDevice {
  /**
   * @param {object} options
   * @param {string} options.uf2 firmware image
   * @param {string} [options.elf] the same firmware's ELF (for the tick counter's address);
   *   default: the UF2's path with .elf
   * @param {string|null} [options.flash] file that keeps the flash contents, or null
   * @param {string} [options.bootrom] RP2040 bootrom B1 image
   * @param {number} [options.quantumCycles] cycles per turn when both cores are awake
   */
  constructor({ uf2, elf, flash = null, bootrom, quantumCycles = QUANTUM_BOTH_CYCLES }) {
    this.quantumCycles = quantumCycles;
    const elfPath = elf ?? uf2.replace(/\.uf2$/, '.elf');
    this.symbols = readElfSymbols(new Uint8Array(readFileSync(elfPath)));
    const ticks = this.symbols.get(TICKS_SYMBOL);
    if (!ticks) {
      throw new DeviceError(`${elfPath} has no symbol ${TICKS_SYMBOL}: not a usbmotion firmware`);
    }
    if (ticks.address < SRAM_BASE || ticks.address % 4 !== 0) {
      throw new DeviceError(`${TICKS_SYMBOL} at 0x${ticks.address.toString(16)} is not in SRAM`);
    }
    this.ticksOffset = ticks.address - SRAM_BASE;
    this.stacks = STACK_SYMBOLS.map(([bottom, top]) => {
      const low = this.symbols.get(bottom);
      const high = this.symbols.get(top);
      return low && high && high.address > low.address
        ? { bottom: low.address - SRAM_BASE, top: high.address - SRAM_BASE }
        : null;
    });
    const patched = patchBootrom(readBootrom(bootrom), FLASH_BREAKPOINTS);
    this.bootromWords = new Uint32Array(patched.image.buffer.slice(0));
    this.breakpoints = patched.byAddress;
    this.flash = new FlashImage(flash);
    this.flash.flashUf2(parseUf2(new Uint8Array(readFileSync(uf2))));
    this.mcu = null;
    this.profile = null;
    this.output = [];
    this.onOutput = null; // (bytes) => void, else output is kept for takeOutput()
    this.fault = null;
    this.worldOptions = null; // the motor outside the chip (attachMotor), kept across power cycles
    this.worldKind = null; // MotorWorld or StepperWorld
    this.world = null;
    this.turnCore = null;
  }

  /**
   * Wires a DC motor, its encoder and two limit switches to the chip's pins (lib/pins.js
   * MotorWorld; options as its constructor's): from now on and on every later power-up,
   * where the motor then is.
   */
  attachMotor(options = {}) {
    this.worldOptions = options;
    this.worldKind = MotorWorld;
    this.world = new MotorWorld(this.pins, this.mcu, options);
    return this.world;
  }

  /**
   * Wires a stepper on a step/direction driver, and its encoder, to the chip's pins (lib/pins.js
   * StepperWorld; options as its constructor's): from now on and on every later power-up.
   */
  attachStepper(options = {}) {
    this.worldOptions = options;
    this.worldKind = StepperWorld;
    this.world = new StepperWorld(this.pins, this.mcu, options);
    return this.world;
  }

  /** The emulated time of the instruction executing now (or the clock's between turns), ns. */
  nowNanos() {
    const core = this.turnCore;
    if (core) {
      return this.turnStartNanos + (core.cycles - this.turnStartCycles) * this.cycleNanos;
    }
    return this.clock.nanos;
  }

  /**
   * A fresh chip on the same flash contents: output and unread input of the last one are lost.
   * @param {object} [options]
   * @param {boolean} [options.hold] keep the timer held from reset (deterministic mode)
   */
  powerUp({ hold = false } = {}) {
    const mcu = new DualRP2040();
    mcu.loadBootrom(this.bootromWords);
    mcu.flash.set(this.flash.bytes);
    // core1 waits in the bootrom for core0's launch sequence; core0 enters the second-stage
    // boot loader at the start of flash (the bootrom's own flash boot needs SSI reads that
    // rp2040js lacks)
    mcu.core.PC = 0x10000000;
    mcu.onBreak = (number) => {
      if (!answerFlashBreakpoint(mcu, this.flash, this.breakpoints, number)) {
        const core = mcu.core;
        this.fault = `core${mcu.coreIndex} stopped at BKPT #${number} at 0x${(core.PC - 2).toString(16)}`;
        core.PC -= core.breakRewind;
        core.waiting = true;
      }
    };
    this.mcu = mcu;
    this.clock = mcu.clock;
    this.sram = mcu.sramView;
    this.cycleNanos = 1e9 / mcu.clkSys;
    this.pins = new PioClock(mcu, () => this.nowNanos(), (nanos) => this.timerNanosAt(nanos));
    this.pins.ticksNow = () => this.ticksDone();
    if (this.worldOptions && this.worldKind === MotorWorld) {
      const where = this.world ? this.world.theta : this.worldOptions.startCount ?? 0;
      this.world = new MotorWorld(this.pins, mcu, { ...this.worldOptions, startCount: where });
    } else if (this.worldOptions) {
      // the stepper's shaft starts again at its count (a power cycle de-energises the driver)
      const where = this.world ? this.world.count : this.worldOptions.startCount ?? 0;
      this.world = new StepperWorld(this.pins, mcu, { ...this.worldOptions, startCount: where });
    }
    for (const stack of this.stacks) {
      if (stack) {
        mcu.sram.fill(STACK_PAINT, stack.bottom, stack.top);
      }
    }
    this.fault = null;
    this.output = [];
    this.host = new CdcHost(mcu.usbCtrl, (data) => this.received(data));
    this.over = [0, 0];
    this.setUpTimerHold(mcu.peripherals[TIMER_KEY]);
    if (hold) {
      this.holdTimer();
    }
  }

  setUpTimerHold(timer) {
    const clock = this.clock;
    this.timer = timer;
    this.heldAt = -1; // timer time (ns) while held, else -1
    this.timerLagNs = 0; // how far the timer is behind the clock: the time it was held
    // alarms of free-running hardware, which never make the device busy: the timer's, and
    // the PWM counters' (the bridge's, with the motor on the pins)
    this.timerAlarms = new Set(timer.alarms.map((alarm) => alarm.clockAlarm));
    for (const channel of this.mcu.pwm.channels) {
      for (const alarm of [channel.alarmA, channel.alarmB, channel.alarmBottom]) {
        this.timerAlarms.add(alarm.clockAlarm);
      }
    }
    const device = this;
    timer.clock = {
      get nanos() {
        return device.heldAt >= 0 ? device.heldAt : clock.nanos - device.timerLagNs;
      },
    };
    timer.alarms.forEach((alarm, index) => {
      alarm.clockAlarm.callback = () => {
        if (device.heldAt < 0) {
          timer.fireAlarm(index);
        }
        // held: the alarm is scheduled again when the timer runs on
      };
    });
  }

  holdTimer() {
    if (this.heldAt < 0) {
      this.heldAt = this.clock.nanos - this.timerLagNs;
    }
  }

  releaseTimer() {
    if (this.heldAt < 0) {
      return;
    }
    const nowMicros = this.heldAt / 1000;
    this.timerLagNs = this.clock.nanos - this.heldAt;
    this.heldAt = -1;
    this.timer.alarms.forEach((alarm, index) => {
      if (!alarm.armed) {
        return;
      }
      const remaining = (alarm.targetMicros - nowMicros) >>> 0;
      if (remaining === 0) {
        this.timer.fireAlarm(index);
      } else {
        alarm.clockAlarm.schedule(remaining * 1000);
      }
    });
  }

  /** The timer's time when the clock reads `nanos` (now, or later in this slice), ns. */
  timerNanosAt(nanos) {
    return this.heldAt >= 0 ? this.heldAt : nanos - this.timerLagNs;
  }

  /** The RP2040 timer's time, ns: emulated time less the time it was held. */
  get timerNanos() {
    return this.heldAt >= 0 ? this.heldAt : this.clock.nanos - this.timerLagNs;
  }

  get timerHeld() {
    return this.heldAt >= 0;
  }

  received(data) {
    if (this.onOutput) {
      this.onOutput(data);
      return;
    }
    const tick = this.ticksDone();
    const last = this.output[this.output.length - 1];
    if (last && last.tick === tick) {
      last.chunks.push(Uint8Array.from(data));
    } else {
      this.output.push({ tick, chunks: [Uint8Array.from(data)] });
    }
  }

  /** Output since the last call: [{tick, bytes}] in order, one entry per tick. */
  takeOutput() {
    const output = this.output.map(({ tick, chunks }) => ({ tick, bytes: Buffer.concat(chunks) }));
    this.output = [];
    return output;
  }

  ticksDone() {
    const low = this.sram.getUint32(this.ticksOffset, true);
    const high = this.sram.getUint32(this.ticksOffset + 4, true);
    return high * 4294967296 + low;
  }

  /**
   * How much of each core's stack has been used since power-up (its high-water mark, from
   * the paint), and its size, bytes; null for a stack the ELF does not name.
   */
  stackUsage() {
    return this.stacks.map((stack) => {
      if (!stack) {
        return null;
      }
      let low = stack.bottom;
      while (low < stack.top && this.mcu.sram[low] === STACK_PAINT) {
        low++;
      }
      return { used: stack.top - low, size: stack.top - stack.bottom };
    });
  }

  busyCycles() {
    return this.mcu.busyCycles();
  }

  /** Emulated time since power-up, ns. */
  get nanos() {
    return this.clock.nanos;
  }

  /** Queues host-to-device bytes (taken by the device as it reads them). */
  send(data) {
    this.host.send(data);
  }

  /** Both cores asleep with nothing for them on the way: no input, no USB transfer. */
  quiescent() {
    if (this.host.queuedBytes > 0 || !this.host.connected) {
      return false;
    }
    for (let alarm = this.clock.nextAlarm; alarm; alarm = alarm.next) {
      if (!this.timerAlarms.has(alarm)) {
        return false;
      }
    }
    return true;
  }

  execute(index, core, budget) {
    this.mcu.select(index);
    this.turnCore = core;
    this.turnStartCycles = core.cycles;
    this.turnStartNanos = this.clock.nanos;
    const target = core.cycles + budget - this.over[index];
    const profile = this.profile;
    if (profile) {
      const counts = profile.cycles[index];
      while (core.cycles < target) {
        const pc = core.PC;
        const before = core.cycles;
        core.executeInstruction();
        counts.set(pc, (counts.get(pc) ?? 0) + core.cycles - before);
        if (core.waiting) {
          break;
        }
      }
    } else {
      while (core.cycles < target) {
        core.executeInstruction();
        if (core.waiting) {
          break;
        }
      }
    }
    this.over[index] = core.waiting ? 0 : core.cycles - target;
    this.turnCore = null;
  }

  /** Starts counting the cycles of every instruction address, per core (slower). */
  startProfile() {
    this.profile = { cycles: [new Map(), new Map()] };
  }

  /**
   * Stops counting; returns the cycles since startProfile per core and function (by the
   * ELF's function symbols; 'bootrom' below 0x4000, '?' where no function covers the
   * address), largest first.
   * @returns {Array<Array<{name: string, cycles: number}>>}
   */
  stopProfile() {
    const profile = this.profile;
    this.profile = null;
    if (!profile) {
      return [[], []];
    }
    // a function without a size (libgcc's assembly ones) reaches to the next function
    const functions = [...this.symbols]
      .filter(([, symbol]) => symbol.type === STT_FUNC)
      .map(([name, symbol]) => ({ name, start: symbol.address & ~1, size: symbol.size }))
      .sort((a, b) => a.start - b.start || b.size - a.size)
      .filter((f, index, all) => index === 0 || f.start !== all[index - 1].start)
      .map((f, index, all) => ({
        name: f.name,
        start: f.start,
        end: f.size > 0 ? f.start + f.size : (all[index + 1]?.start ?? f.start + 2),
      }));
    const nameOf = (pc) => {
      let low = 0;
      let high = functions.length - 1;
      while (low <= high) {
        const middle = (low + high) >> 1;
        const f = functions[middle];
        if (pc < f.start) {
          high = middle - 1;
        } else if (pc >= f.end) {
          low = middle + 1;
        } else {
          return f.name;
        }
      }
      return pc < 0x4000 ? 'bootrom' : '?';
    };
    return profile.cycles.map((counts) => {
      const byName = new Map();
      for (const [pc, cycles] of counts) {
        const name = nameOf(pc);
        byName.set(name, (byName.get(name) ?? 0) + cycles);
      }
      return [...byName].map(([name, cycles]) => ({ name, cycles })).sort((a, b) => b.cycles - a.cycles);
    });
  }

  /**
   * Runs both cores until the clock reaches endNanos or a stop condition holds.
   * @param {number} endNanos
   * @param {{ticks?: number, settle?: boolean, core1Untimed?: boolean}} [stop] ticks: stop
   *   (and hold the timer) once that many ticks are done; settle: stop once quiescent;
   *   core1Untimed: hold the timer whenever core1 is awake
   * @returns {'time'|'ticks'|'settled'|'idle'}
   */
  advance(endNanos, stop = {}) {
    const mcu = this.mcu;
    const clock = this.clock;
    const core0 = mcu.cores[0];
    const cycleNanos = 1e9 / mcu.clkSys;
    const targetTicks = stop.ticks ?? -1;
    const settle = stop.settle === true;
    const core1Untimed = stop.core1Untimed === true;
    for (;;) {
      if (this.fault) {
        throw new DeviceError(this.fault);
      }
      const now = clock.nanos;
      if (now >= endNanos) {
        return 'time';
      }
      const core1 = mcu.cores[1];
      const run0 = !core0.waiting;
      const run1 = !mcu.core1Off && !core1.waiting;
      if (core1Untimed) {
        // the timer stands still while core1 works: a tick costs no timer time, so however
        // many cycles it takes, the next one is due a whole period later (no catch-up)
        if (run1) {
          this.holdTimer();
        } else {
          this.releaseTimer();
        }
      }
      let slice = endNanos - now;
      const next = clock.nextAlarm;
      if (next && next.nanos - now < slice) {
        slice = next.nanos - now;
      }
      const world = this.heldAt < 0 ? this.world : null; // the world stands still with the timer
      if (!run0 && !run1) {
        if (settle && this.quiescent()) {
          return 'settled';
        }
        if (!next) {
          if (endNanos === Infinity) {
            return 'idle';
          }
          slice = endNanos - now;
        }
        if (world) {
          slice = Math.min(slice, WORLD_SLICE_NS);
          world.advance(now, now + slice, now - this.timerLagNs, now + slice - this.timerLagNs);
        }
        this.pins.catchUp(now + slice);
        clock.tick(slice);
        continue;
      }
      const quantum = (run0 && run1 ? this.quantumCycles : QUANTUM_ONE_CYCLES) * cycleNanos;
      if (quantum < slice) {
        slice = quantum;
      }
      if (world) {
        slice = Math.min(slice, WORLD_SLICE_NS);
        world.advance(now, now + slice, now - this.timerLagNs, now + slice - this.timerLagNs);
      }
      if (slice > 0) {
        const budget = slice / cycleNanos;
        if (run0) {
          this.execute(0, core0, budget);
        }
        if (run1) {
          this.execute(1, core1, budget);
        }
      }
      this.pins.catchUp(now + slice);
      if (targetTicks >= 0 && this.ticksDone() >= targetTicks) {
        // hold before the clock moves on, so the next tick's alarm cannot fire
        this.holdTimer();
        clock.tick(slice);
        return 'ticks';
      }
      clock.tick(slice);
    }
  }

  /** Deterministic: lets core0 finish what it has (timer held); throws if it never does. */
  settle() {
    this.holdTimer();
    const reason = this.advance(this.clock.nanos + SETTLE_LIMIT_NS, { settle: true });
    if (reason !== 'settled') {
      throw new DeviceError(
        `device still busy after ${SETTLE_LIMIT_NS / 1e9} s of emulated time with the timer held`,
      );
    }
  }

  /**
   * Free running from reset, as a chip plugged in: the time (emulated ns since reset) the
   * firmware enabled USB (its pull-up: the host then resets the bus, 10 ms, and enumerates),
   * the port was configured, `data` was sent the moment it was, and the first byte of the
   * reply came back, with each core's busy cycles then. The device is left running free (a
   * deterministic session needs power_up again).
   * @param {Uint8Array} data
   */
  bootToFirstReply(data) {
    this.powerUp();
    const usb = this.mcu.usbCtrl;
    const enabled = usb.onUSBEnabled;
    let usbEnabledNs = -1;
    usb.onUSBEnabled = () => {
      usbEnabledNs = this.nanos;
      enabled();
    };
    let replyNs = -1;
    this.onOutput = () => {
      if (replyNs < 0) {
        replyNs = this.nanos;
      }
    };
    const step = 10e3;
    while (!this.host.connected && this.nanos < SETTLE_LIMIT_NS) {
      this.advance(this.nanos + step);
    }
    const configuredNs = this.nanos;
    this.send(data);
    while (replyNs < 0 && this.nanos < configuredNs + SETTLE_LIMIT_NS) {
      this.advance(this.nanos + step);
    }
    this.onOutput = null;
    if (replyNs < 0) {
      throw new DeviceError('no reply after power-up');
    }
    return { usbEnabledNs, configuredNs, replyNs, cycles: this.busyCycles() };
  }

  /** Deterministic: power-up with the timer held until USB is up and core0 sleeps (tick 0). */
  bootHeld() {
    this.powerUp({ hold: true });
    this.settle();
  }

  /**
   * Deterministic: runs `count` more servo ticks, one at a time: after each, the timer is held
   * until core0 has printed what the tick recorded and the host has taken it. Output stamped
   * with tick N is so what the device printed after tick N, whatever USB's latency (the
   * Python device stamps a line with the tick it printed at). The timer is also held while
   * core1 runs a tick: a tick longer than the servo period (which on the chip would make the
   * next ones late, run back to back to catch up) still ends one period before the next.
   * The cycles every tick took are counted all the same (busyCycles).
   */
  runTicks(count) {
    for (let done = 0; done < count; done++) {
      const target = this.ticksDone() + 1;
      this.releaseTimer();
      const reason = this.advance(Infinity, { ticks: target, core1Untimed: true });
      if (reason !== 'ticks') {
        throw new DeviceError(`the servo stopped ticking at tick ${this.ticksDone()}`);
      }
      this.settle();
    }
    this.settle();
  }

  /** Deterministic: gives the device bytes at the current tick boundary and lets it handle them. */
  feed(data) {
    this.holdTimer();
    this.send(data);
    this.settle();
  }
}
