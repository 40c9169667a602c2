// What the firmware's pins need from the emulated chip beyond rp2040js, and the world on the
// other side of them.
//
// rp2040js runs its PIO on the host's event loop (1,000 steps per setTimeout, unrelated to
// the emulated clock) and gives core1 no GPIO interrupt enables. PioClock steps the state
// machines in lockstep with the emulated clock instead, one instruction per system clock
// cycle (the firmware's programs use no delays and a clock divider of 1): lazily, up to the
// time of each input pin change and of each access to a PIO register by either core. A
// machine whose state repeats pass after pass with its RX FIFO full and no input change is
// fast-forwarded by whole passes (what it would do there is unobservable). The GPIO
// interrupt registers of core1 (PROC1_INTE/INTF/INTS) are those of core0: one set of enables
// serves both cores (the firmware enables GPIO interrupts on core1 only).
//
// MotorWorld is the motor outside the chip: a brushed DC motor on a two-input H-bridge (its
// voltage from the PWM compare levels of the bridge's two outputs, the supply times the
// difference of their duties, sampled at the start of each slice of emulated time: the
// electrical time constant of such a motor, about a millisecond, is far above the PWM
// period), integrated exactly under that constant voltage with the simulated motor's model
// (PROTOCOL.md, "The model": a first-order velocity with Coulomb friction that stops the
// shaft instead of reversing it, and hard stops beyond the switches), in binary64; its
// quadrature encoder's A/B pins (an edge at each count, at the time the motion crosses it)
// and its two limit switches (closed, low, at or beyond their positions; open, high through
// the pull-up, otherwise), optionally bouncing; and a probe touching a surface (closed, low,
// while the shaft is at or beyond it on its side). EncoderSweep drives the encoder pins alone
// at a set rate, for the decoder's own tests. outputLevels reads the outputs of call 42 off
// their pins: the digital ones' levels and the PWM ones' duties.
//
// The step generator's block (STEP_PIO, firmware/src/rp2040/step_dir.pio) runs on the timer's
// time instead of the clock's: on the chip its tick clock and the servo's alarms come from
// one crystal and keep in step, and the harness's held timer (the deterministic mode's
// pause, in which no device time passes) holds it too, as it holds the motor world. Its
// machines interact (one raises the PIO flag the other waits on), so they are stepped
// together, cycle by cycle, skipping ahead over the cycles in which every one of them is
// stalled (on a flag, or on an empty TX FIFO) or counting down a one-instruction delay loop
// (`jmp x--`/`jmp y--` to itself); rp2040js's FIFO join (SHIFTCTRL FJOIN_TX: an 8-deep TX
// FIFO), which it lacks, is added. Every change of that block's pins and every PIO flag it
// raises can be recorded with its time (capture).

const IO_BANK0_KEY = 0x40014;
const PADS_BANK0_KEY = 0x4001c;
const PROC0_INTE0 = 0x100;
const PROC1_INTE0 = 0x130;
const PROC1_INTS3 = 0x15c;
const PWM_CHANNEL_BYTES = 0x14;
const PWM_CC = 0x0c;
const PWM_TOP = 0x10;
const PWM_CSR_EN = 1;
const IO_GPIO_CTRL = 0x04; // + 8 per GPIO
const IO_FUNCSEL_MASK = 0x1f;
const FUNCSEL_PWM = 4;
/** (B, A) of each count modulo 4, forward: A rises, B rises, A falls, B falls. */
const GRAY = [0b00, 0b01, 0b11, 0b10];
/** The step generator's PIO block (firmware/src/rp2040/pins.h STEP_PIO). */
export const STEP_PIO = 1;
/** A state machine's SHIFTCTRL, as an offset from its CLKDIV. */
const SM_SHIFTCTRL = 0x08;
/** JMP conditions X-- and Y--; rp2040js's wait types IRQ and TX FIFO (a blocking pull). */
const JMP_X_DEC = 0b010;
const JMP_Y_DEC = 0b100;
const OP_IRQ = 0b110;
const IRQ_CLEAR_OR_WAIT = 0x60;
const WAIT_TX_FIFO = 3;
const WAIT_IRQ = 4;
/** Steps a machine must run since its last input change before it may be fast-forwarded. */
const SETTLE_STEPS = 64;

/** Locks the chip's PIO blocks to its clock and gives core1 GPIO interrupts. */
export class PioClock {
  /**
   * @param {object} mcu the DualRP2040
   * @param {() => number} now the emulated time of the instruction executing, ns
   */
  constructor(mcu, now, timerAt = (nanos) => nanos) {
    this.mcu = mcu;
    this.now = now;
    this.timerAt = timerAt;
    this.cycleNanos = 1e9 / mcu.clkSys;
    this.nanos = 0; // every clocked machine has run up to here
    this.timedNanos = 0; // the step generator's block has run up to here, timer time
    this.timed = mcu.pio[STEP_PIO];
    this.loops = new Map(); // the step block's machine -> the pc of its last instruction
    this.capture = null; // {pins, edges: [[pin, level, ns]], flags: [[flag, ns, ticks]]}
    this.ticksNow = () => 0;
    this.edgeListeners = []; // (pin, level, timerNanos) for the step block's pins
    this.events = []; // [{nanos, pin, value}] in time order
    this.sources = []; // inputs that run on the clock's own time (AbsolutePwm), emitting lazily
    this.marks = new Map(); // machine -> its state at the start of a pass, for fast-forward
    this.positions = new Map(); // machine -> the steps it has run
    this.sinceInput = 0; // steps since the last input change
    for (const pio of mcu.pio) {
      for (const machine of pio.machines) {
        joinFifos(machine);
      }
      pio.run = () => {}; // stepped here, not on the host's event loop
      const read = pio.readUint32.bind(pio);
      const write = pio.writeUint32.bind(pio);
      pio.readUint32 = (offset) => {
        this.catchUp(this.now());
        return read(offset);
      };
      pio.writeUint32 = (offset, value) => {
        this.catchUp(this.now());
        write(offset, value);
      };
    }
    const io = mcu.peripherals[IO_BANK0_KEY];
    const ioRead = io.readUint32.bind(io);
    const ioWrite = io.writeUint32.bind(io);
    const shared = (offset) =>
      offset >= PROC1_INTE0 && offset <= PROC1_INTS3 ? offset - (PROC1_INTE0 - PROC0_INTE0) : offset;
    io.readUint32 = (offset) => ioRead(shared(offset));
    io.writeUint32 = (offset, value) => ioWrite(shared(offset), value);
    // an input nothing outside drives reads what its pad's pull resistor gives it
    this.driven = new Set();
    const pads = mcu.peripherals[PADS_BANK0_KEY];
    const padsWrite = pads.writeUint32.bind(pads);
    pads.writeUint32 = (offset, value) => {
      padsWrite(offset, value);
      this.applyPulls();
    };
  }

  applyPulls() {
    for (const pin of this.mcu.gpio) {
      if (!this.driven.has(pin.index) && pin.pullupEnabled !== pin.rawInputValue) {
        pin.setInputValue(pin.pullupEnabled && !pin.pulldownEnabled);
      }
    }
  }

  /** Pins driven from outside from now on (their pulls no longer matter). */
  drive(...pins) {
    for (const pin of pins) {
      this.driven.add(pin);
    }
  }

  /** An input pin takes `value` at `nanos` (not before the time already run). */
  schedule(nanos, pin, value) {
    const events = this.events;
    let index = events.length;
    while (index > 0 && events[index - 1].nanos > nanos) {
      index--;
    }
    events.splice(index, 0, { nanos, pin, value });
  }

  /** Time of the next scheduled input change, or Infinity. */
  get nextEventNanos() {
    return this.events.length > 0 ? this.events[0].nanos : Infinity;
  }

  /** Runs every enabled state machine up to `nanos`, applying the input changes due. */
  catchUp(nanos) {
    for (const source of this.sources) {
        source.emitUpTo(nanos);
    }
    const events = this.events;
    while (events.length > 0 && events[0].nanos <= nanos) {
      const event = events.shift();
      this.stepTo(event.nanos);
      this.mcu.gpio[event.pin].setInputValue(event.value);
      this.sinceInput = 0;
      this.marks.clear();
    }
    this.stepTo(nanos);
    this.stepTimedTo(this.timerAt(nanos));
  }

  stepTo(nanos) {
    const steps = Math.floor((nanos - this.nanos) / this.cycleNanos);
    if (steps <= 0) {
      return;
    }
    this.nanos += steps * this.cycleNanos;
    for (const pio of this.mcu.pio) {
      if (pio.stopped || pio === this.timed) {
        continue;
      }
      for (const machine of pio.machines) {
        if (machine.enabled) {
          this.run(machine, steps);
        }
      }
      pio.checkChangedPins();
    }
    this.sinceInput += steps;
  }

  /** Runs the step generator's block up to `nanos` of timer time, its machines in lockstep. */
  stepTimedTo(nanos) {
    const steps = Math.floor((nanos - this.timedNanos) / this.cycleNanos);
    if (steps <= 0) {
      return;
    }
    const pio = this.timed;
    const start = this.timedNanos;
    this.timedNanos += steps * this.cycleNanos;
    if (pio.stopped) {
      return;
    }
    const machines = pio.machines.filter((machine) => machine.enabled);
    const loops = this.loops;
    let left = steps;
    let done = 0;
    while (left > 0) {
      let skip = left;
      for (const machine of machines) {
        skip = Math.min(skip, this.idleSteps(pio, machine));
        if (skip === 0) {
          break;
        }
      }
      if (skip > 0) {
        for (const machine of machines) {
          if (!machine.waiting) {
            // a delay loop: `jmp x-- self` or `jmp y-- self`, taken `skip` more times
            if (((pio.instructions[machine.pc] >> 5) & 7) === JMP_X_DEC) {
              machine.x -= skip;
            } else {
              machine.y -= skip;
            }
          }
        }
        left -= skip;
        done += skip;
        continue;
      }
      const nanos = start + done * this.cycleNanos;
      const values = pio.pinValues;
      for (const machine of machines) {
        const pc = machine.pc;
        const instruction = machine.waiting ? -1 : pio.instructions[pc];
        machine.step();
        loops.set(machine, machine.waiting ? -1 : pc);
        if (instruction >> 13 === OP_IRQ && (instruction & IRQ_CLEAR_OR_WAIT) === 0 && this.capture) {
          // every flag raised, even one still up from before (a start no frame waited on)
          const index = instruction & 0x1f;
          const flag = index & 0x10 ? (index & 4) | (((index & 3) + machine.index) & 3) : index & 7;
          this.capture.flags.push([flag, nanos, this.ticksNow()]);
        }
      }
      const changed = pio.pinValues ^ values;
      if (changed) {
        this.pinsChanged(changed, pio.pinValues, nanos);
      }
      left--;
      done++;
    }
    pio.checkChangedPins();
  }

  /**
   * The cycles from now on in which `machine` certainly does nothing observable but count a
   * delay loop down or stay stalled: 0 when it may act at its next step.
   */
  idleSteps(pio, machine) {
    if (machine.waiting) {
      if (machine.waitType === WAIT_IRQ) {
        return ((pio.irq >> machine.waitIndex) & 1) === Number(machine.waitPolarity) ? 0 : Infinity;
      }
      if (machine.waitType === WAIT_TX_FIFO) {
        return machine.txFIFO.empty ? Infinity : 0;
      }
      return 0;
    }
    const instruction = pio.instructions[machine.pc];
    const condition = (instruction >> 5) & 7;
    const delayMask = (1 << (5 - machine.sidesetCount)) - 1;
    if (instruction >> 13 !== 0 || (instruction & 0x1f) !== machine.pc
        || ((instruction >> 8) & delayMask) !== 0 || this.loops.get(machine) !== machine.pc) {
      return 0;
    }
    if (condition === JMP_X_DEC) {
      return machine.x >>> 0;
    }
    if (condition === JMP_Y_DEC) {
      return machine.y >>> 0;
    }
    return 0;
  }

  pinsChanged(changed, values, nanos) {
    for (let pin = 0; pin < 30; pin++) {
      if (changed & (1 << pin)) {
        const level = (values >> pin) & 1;
        if (this.capture && this.capture.pins.has(pin)) {
          this.capture.edges.push([pin, level, nanos]);
        }
        for (const listener of this.edgeListeners) {
          listener(pin, level, nanos);
        }
      }
    }
  }

  /** Records the step block's pin changes (of `pins`) and flags from now on. */
  startCapture(pins) {
    this.capture = { pins: new Set(pins), edges: [], flags: [] };
  }

  /** What was recorded since the last call (or startCapture); recording goes on. */
  takeCapture() {
    const capture = this.capture;
    if (!capture) {
      return { edges: [], flags: [] };
    }
    const taken = { edges: capture.edges, flags: capture.flags };
    capture.edges = [];
    capture.flags = [];
    return taken;
  }

  run(machine, steps) {
    // `position`: the steps this machine has run; a mark holds the position it was taken at,
    // so a pass's length is measured within one call or across calls alike
    let left = steps;
    let since = this.sinceInput;
    let position = this.positions.get(machine) ?? 0;
    while (left > 0) {
      if (since >= SETTLE_STEPS && machine.pc === machine.wrapBottom && machine.rxFIFO.full) {
        const mark = this.marks.get(machine);
        if (mark && sameState(mark, machine)) {
          const period = position - mark.position;
          if (period > 0 && left >= period) {
            const skipped = Math.floor(left / period) * period;
            left -= skipped;
            position += skipped;
            mark.position = position;
            continue;
          }
        } else {
          this.marks.set(machine, snapshot(machine, position));
        }
      }
      machine.step();
      left--;
      since++;
      position++;
    }
    this.positions.set(machine, position);
  }
}

/** rp2040js's FIFO join: SHIFTCTRL's FJOIN_TX gives the machine one 8-deep TX FIFO (and no
 * RX FIFO), FJOIN_RX one 8-deep RX FIFO; the FIFOs are emptied, as the chip does. */
function joinFifos(machine) {
  const write = machine.writeUint32.bind(machine);
  let join = 0;
  machine.writeUint32 = (offset, value) => {
    write(offset, value);
    if (offset === SM_SHIFTCTRL && value >>> 30 !== join) {
      join = value >>> 30;
      const joinTx = join & 1;
      const joinRx = join >> 1;
      const FifoClass = machine.txFIFO.constructor;
      machine.txFIFO = new FifoClass(joinTx ? 8 : joinRx ? 0 : 4);
      machine.rxFIFO = new FifoClass(joinRx ? 8 : joinTx ? 0 : 4);
    }
  };
}

function snapshot(machine, position) {
  return {
    position,
    pc: machine.pc,
    x: machine.x,
    y: machine.y,
    isr: machine.inputShiftReg,
    isc: machine.inputShiftCount,
    osr: machine.outputShiftReg,
    osc: machine.outputShiftCount,
  };
}

function sameState(mark, machine) {
  return (
    mark.pc === machine.pc &&
    mark.x === machine.x &&
    mark.y === machine.y &&
    mark.isr === machine.inputShiftReg &&
    mark.isc === machine.inputShiftCount &&
    mark.osr === machine.outputShiftReg &&
    mark.osc === machine.outputShiftCount &&
    !machine.waiting
  );
}

/** The frame of an AS5161-style PWM angle output, in the sensor's clock periods
 * (firmware/src/device/absenc.h): a start high, the 12-bit code high, the rest of the data
 * part and an end low. */
export const PWM_FRAME = { head: 128, codes: 4096, tail: 128, clocks: 128 + 4095 + 128 };

/** An absolute encoder's PWM at power-up: a 920 Hz frame, its clock exact, the magnet at 0. */
export const DEFAULT_ABSOLUTE = { frameHz: 920, clockScale: 1, magnetTurns: 0 };

/**
 * An absolute magnetic encoder's PWM output on the encoder's channel A pin (AS5161-style): a
 * frame every 4351 of its clock periods, high for 128 + the code of the shaft's angle at the
 * frame's start (floor of its fraction of a turn x 4096). It runs on the clock's own time,
 * not the timer's: an oscillator of its own, going on while the harness holds the timer (the
 * world stands still then, so the angle does too). `clockScale` stretches its clock (1.1: 10 %
 * slow); `magnetTurns` is where the magnet sits on the shaft, a fraction of a turn. `silence()`
 * stops it with the line low (a cut wire, a dead sensor) and `resume()` starts it again.
 */
export class AbsolutePwm {
  /**
   * @param {PioClock} clock
   * @param {() => number} turns the shaft's angle now, in turns (any real number)
   * @param {object} options DEFAULT_ABSOLUTE's keys
   */
  constructor(clock, turns, options = {}) {
    for (const key of Object.keys(options)) {
      if (!(key in DEFAULT_ABSOLUTE)) {
        throw new Error(`absolute encoder option ${JSON.stringify(key)} is unknown; known: `
          + `${Object.keys(DEFAULT_ABSOLUTE).join(', ')}`);
      }
    }
    const o = { ...DEFAULT_ABSOLUTE, ...options };
    if (!(o.frameHz > 0) || !(o.clockScale > 0) || typeof o.magnetTurns !== 'number') {
      throw new Error(`absolute encoder frameHz ${o.frameHz} and clockScale ${o.clockScale} must be`
        + ` above 0 and magnetTurns ${o.magnetTurns} a number`);
    }
    this.clock = clock;
    this.turns = turns;
    this.magnetTurns = o.magnetTurns;
    this.clockNanos = (1e9 / (o.frameHz * PWM_FRAME.clocks)) * o.clockScale;
    this.nextRise = clock.nanos + this.clockNanos; // the line low until the first frame
    this.on = true;
    this.frames = 0;
    this.lastCode = -1;
    clock.drive(PIN_MAP.encoderA);
    clock.mcu.gpio[PIN_MAP.encoderA].setInputValue(false);
    clock.sources.push(this);
  }

  /** The code of the shaft's angle now: 0..4095. */
  code() {
    const turns = this.turns() + this.magnetTurns;
    const fraction = turns - Math.floor(turns);
    return Math.min(Math.floor(fraction * PWM_FRAME.codes), PWM_FRAME.codes - 1);
  }

  /** Schedules every frame that starts by `nanos`. */
  emitUpTo(nanos) {
    while (this.on && this.nextRise <= nanos) {
      const code = this.code();
      this.clock.schedule(this.nextRise, PIN_MAP.encoderA, true);
      this.clock.schedule(this.nextRise + (PWM_FRAME.head + code) * this.clockNanos, PIN_MAP.encoderA, false);
      this.nextRise += PWM_FRAME.clocks * this.clockNanos;
      this.frames++;
      this.lastCode = code;
    }
  }

  silence() {
    this.on = false;
  }

  resume() {
    if (!this.on) {
      this.on = true;
      this.nextRise = Math.max(this.nextRise, this.clock.nanos + this.clockNanos);
    }
  }

  get state() {
    return { on: this.on, frames: this.frames, code: this.lastCode };
  }
}

/** The default motor of PROTOCOL.md (calls 13-17, 32, 33 at power-up). */
export const DEFAULT_MOTOR = {
  supplyV: 12,
  torqueConstantNmPerA: 0.3346,
  resistanceOhm: 2.182,
  inertiaKgM2: 1.1e-3,
  viscousNmPerRadS: 500e-6,
  loadNm: 0.05,
  countsPerRevolution: 1920,
};

const MOTOR_KEYS = new Set([
  ...Object.keys(DEFAULT_MOTOR),
  'pins', 'lower', 'upper', 'overtravel', 'bounce', 'bounceNanos', 'startCount',
  'probeSide', 'probePosition', 'absolute',
]);

/** The firmware's pin map (firmware/src/rp2040/pins.h). */
export const PIN_MAP = {
  encoderA: 2, encoderB: 3, in1: 6, in2: 7, enable: 8, lower: 10, upper: 11, probe: 12,
};

/** The outputs of call 42 (pins.h): 0 and 1 digital, 2 and 3 PWM (slice 0, A and B). */
export const OUTPUT_PINS = [13, 14, 16, 17];

/**
 * The outputs as their pins show them now, per mille: a digital output's level (1000 while
 * the pin drives high, 0 otherwise), a PWM output's duty (its compare level over the slice's
 * period, 0 while the slice is off or the pin is not the PWM's).
 */
export function outputLevels(mcu) {
  return OUTPUT_PINS.map((pin, output) => {
    if (output < 2) {
      const gpio = mcu.gpio[pin];
      return gpio.outputEnable && gpio.outputValue ? 1000 : 0;
    }
    const io = mcu.peripherals[IO_BANK0_KEY];
    if ((io.readUint32(IO_GPIO_CTRL + 8 * pin) & IO_FUNCSEL_MASK) !== FUNCSEL_PWM) {
      return 0;
    }
    const pwm = mcu.pwm;
    const base = ((pin >> 1) & 7) * PWM_CHANNEL_BYTES;
    if (!(pwm.readUint32(base) & PWM_CSR_EN)) {
      return 0;
    }
    const cc = pwm.readUint32(base + PWM_CC);
    const full = pwm.readUint32(base + PWM_TOP) + 1;
    const level = pin & 1 ? cc >>> 16 : cc & 0xffff;
    return (Math.min(level, full) * 1000) / full;
  });
}

export class MotorWorld {
  /**
   * @param {PioClock} clock
   * @param {object} mcu
   * @param {object} options the motor (DEFAULT_MOTOR's keys), `lower`/`upper` switch
   *   positions in counts from power-up (default: none), `overtravel` (200 counts from each
   *   switch to its hard stop), `bounce` (each switch edge bounces this many times, 0) and
   *   `bounceNanos` (apart, 50 us), `startCount` (the shaft's count at power-up, 0), and the
   *   probe's surface as call 40 gives it: `probeSide` (0 none, the default: the probe pin
   *   is left to its pull-up; 1 the probe closes at or below `probePosition`, 2 at or above
   *   it) and `probePosition` (counts from power-up, 0); `absolute`: an absolute encoder
   *   (AbsolutePwm, its options) whose PWM drives channel A instead of the quadrature
   */
  constructor(clock, mcu, options = {}) {
    for (const key of Object.keys(options)) {
      if (!MOTOR_KEYS.has(key)) {
        throw new Error(`motor option ${JSON.stringify(key)} is unknown; known: ${[...MOTOR_KEYS].join(', ')}`);
      }
    }
    const m = { ...DEFAULT_MOTOR, ...options };
    for (const key of Object.keys(DEFAULT_MOTOR)) {
      if (!(typeof m[key] === 'number' && m[key] > 0) && !(key === 'viscousNmPerRadS' || key === 'loadNm')) {
        throw new Error(`motor ${key} ${JSON.stringify(m[key])} must be a number above 0`);
      }
    }
    this.clock = clock;
    this.mcu = mcu;
    this.pins = PIN_MAP;
    const radPerCount = (2 * Math.PI) / m.countsPerRevolution;
    const damping = (m.torqueConstantNmPerA ** 2) / m.resistanceOhm + m.viscousNmPerRadS;
    this.supplyV = m.supplyV;
    this.tauS = m.inertiaKgM2 / damping;
    this.countsPerSPerV = m.torqueConstantNmPerA / m.resistanceOhm / damping / radPerCount;
    this.frictionCountsPerS = m.loadNm / damping / radPerCount;
    this.lower = options.lower ?? -Infinity;
    this.upper = options.upper ?? Infinity;
    const overtravel = options.overtravel ?? 200;
    this.stopLow = this.lower - overtravel;
    this.stopHigh = this.upper + overtravel;
    this.bounce = options.bounce ?? 0;
    this.bounceNanos = options.bounceNanos ?? 50e3;
    this.theta = options.startCount ?? 0; // counts, not wrapped
    this.omega = 0; // counts/s
    this.count = Math.floor(this.theta);
    this.edgesEmitted = 0;
    this.switchEdges = 0;
    this.switchPinChanges = 0; // the switch edges and their bounces, as the pins saw them
    this.closed = [this.count <= this.lower, this.count >= this.upper];
    this.probeSide = options.probeSide ?? 0;
    this.probePosition = options.probePosition ?? 0;
    if (![0, 1, 2].includes(this.probeSide) || !Number.isInteger(this.probePosition)) {
      throw new Error(`motor probeSide ${JSON.stringify(this.probeSide)} must be 0, 1 or 2 and`
        + ` probePosition ${JSON.stringify(this.probePosition)} an integer`);
    }
    this.probeClosed = this.touching(this.count);
    this.probeEdges = 0;
    clock.drive(PIN_MAP.encoderA, PIN_MAP.encoderB, PIN_MAP.lower, PIN_MAP.upper);
    this.countsPerRevolution = m.countsPerRevolution;
    this.pwm = options.absolute
      ? new AbsolutePwm(clock, () => this.theta / this.countsPerRevolution, options.absolute) : null;
    if (!this.pwm) {
      this.setEncoderPins(this.count, 0);
    }
    for (let i = 0; i < 2; i++) {
      mcu.gpio[i === 0 ? PIN_MAP.lower : PIN_MAP.upper].setInputValue(!this.closed[i]);
    }
    if (this.probeSide !== 0) {
      clock.drive(PIN_MAP.probe);
      mcu.gpio[PIN_MAP.probe].setInputValue(!this.probeClosed);
    }
  }

  /** The probe touches its surface at this count (call 40's rule). */
  touching(count) {
    return (this.probeSide === 1 && count <= this.probePosition)
      || (this.probeSide === 2 && count >= this.probePosition);
  }

  setEncoderPins(count, nanos) {
    const state = GRAY[((count % 4) + 4) % 4];
    if (nanos <= 0) {
      this.mcu.gpio[PIN_MAP.encoderA].setInputValue((state & 1) !== 0);
      this.mcu.gpio[PIN_MAP.encoderB].setInputValue((state & 2) !== 0);
    }
    return state;
  }

  /** The bridge's voltage now: the supply times IN1's duty less IN2's. */
  get voltage() {
    const pwm = this.mcu.pwm;
    const slice = PIN_MAP.in1 >> 1;
    const csr = pwm.readUint32(slice * PWM_CHANNEL_BYTES);
    if (!(csr & PWM_CSR_EN)) {
      return 0;
    }
    const cc = pwm.readUint32(slice * PWM_CHANNEL_BYTES + PWM_CC);
    const full = pwm.readUint32(slice * PWM_CHANNEL_BYTES + PWM_TOP) + 1;
    const duty = (level) => Math.min(level, full) / full;
    return this.supplyV * (duty(cc & 0xffff) - duty(cc >>> 16));
  }

  get enabled() {
    return this.mcu.gpio[PIN_MAP.enable].outputValue;
  }

  /** Integrates the motor over [fromNanos, toNanos) of emulated time and schedules its pins. */
  advance(fromNanos, toNanos) {
    const h = (toNanos - fromNanos) / 1e9;
    if (h <= 0) {
      return;
    }
    const v = this.voltage;
    const drive = this.countsPerSPerV * v;
    let direction = Math.sign(this.omega);
    if (direction === 0) {
      if (Math.abs(drive) <= this.frictionCountsPerS) {
        return;
      }
      direction = Math.sign(drive);
    }
    const target = drive - direction * this.frictionCountsPerS;
    const decay = -Math.expm1(-h / this.tauS);
    const lag = h - this.tauS * decay;
    const gap = this.omega - target;
    let omega = this.omega - gap * decay;
    let travel = this.omega * h - gap * lag;
    if (direction > 0) {
      omega = Math.max(omega, 0);
      travel = Math.max(travel, 0);
    } else {
      omega = Math.min(omega, 0);
      travel = Math.min(travel, 0);
    }
    let theta = this.theta + travel;
    if (theta <= this.stopLow) {
      theta = this.stopLow;
      omega = 0;
    } else if (theta >= this.stopHigh) {
      theta = this.stopHigh;
      omega = 0;
    }
    // an edge at each count crossed, at the time the motion (linear over the slice) crosses it
    const from = this.theta;
    const newCount = Math.floor(theta);
    while (this.count !== newCount) {
      const next = newCount > this.count ? this.count + 1 : this.count - 1;
      const boundary = newCount > this.count ? next : this.count;
      const at = fromNanos + ((boundary - from) / (theta - from)) * (toNanos - fromNanos);
      this.emitCount(next, Math.min(Math.max(at, fromNanos), toNanos));
      this.count = next;
    }
    this.theta = theta;
    this.omega = omega;
  }

  emitCount(count, nanos) {
    const before = GRAY[((this.count % 4) + 4) % 4];
    const after = GRAY[((count % 4) + 4) % 4];
    const changed = before ^ after;
    const pin = changed & 1 ? PIN_MAP.encoderA : PIN_MAP.encoderB;
    if (!this.pwm) {
      this.clock.schedule(nanos, pin, ((changed & 1 ? after : after >> 1) & 1) !== 0);
    }
    this.edgesEmitted++;
    const closed = [count <= this.lower, count >= this.upper];
    for (let i = 0; i < 2; i++) {
      if (closed[i] !== this.closed[i]) {
        this.closed[i] = closed[i];
        this.switchEdges++;
        const pinNumber = i === 0 ? PIN_MAP.lower : PIN_MAP.upper;
        const level = !closed[i]; // closed pulls the pin low
        this.clock.schedule(nanos, pinNumber, level);
        this.switchPinChanges += 1 + 2 * this.bounce;
        for (let b = 0; b < this.bounce; b++) {
          this.clock.schedule(nanos + (b + 0.5) * this.bounceNanos, pinNumber, !level);
          this.clock.schedule(nanos + (b + 1) * this.bounceNanos, pinNumber, level);
        }
      }
    }
    const touching = this.touching(count);
    if (touching !== this.probeClosed) {
      this.probeClosed = touching;
      this.probeEdges++;
      this.clock.schedule(nanos, PIN_MAP.probe, !touching); // touching pulls the pin low
    }
  }

  /** What the world holds, for the tests. */
  get state() {
    return {
      count: this.count,
      theta: this.theta,
      omega: this.omega,
      voltage: this.voltage,
      enabled: this.enabled,
      closed: this.closed.slice(),
      edges: this.edgesEmitted,
      switchEdges: this.switchEdges,
      switchPinChanges: this.switchPinChanges,
      probeClosed: this.probeClosed,
      probeEdges: this.probeEdges,
      pwm: this.pwm ? this.pwm.state : null,
    };
  }
}

/**
 * The encoder pins alone, stepping `counts` counts (negative: backwards) from `startNanos`,
 * evenly at `countsPerS`; `skip` lists the counts (1-based) at which both pins change at once
 * instead of one: an edge the decoder cannot see, for the test of the test.
 */
export function sweepEncoder(clock, { startNanos, counts, countsPerS, startCount = 0, skip = [] }) {
  const step = counts >= 0 ? 1 : -1;
  const spacing = 1e9 / countsPerS;
  const skipped = new Set(skip);
  clock.drive(PIN_MAP.encoderA, PIN_MAP.encoderB);
  let count = startCount;
  let state = GRAY[((count % 4) + 4) % 4];
  // the pins at startCount's state first (from the pull-ups' 3, say: both pins at once, so
  // not a count), a microsecond before the sweep
  clock.schedule(startNanos - 1e3, PIN_MAP.encoderA, (state & 1) !== 0);
  clock.schedule(startNanos - 1e3, PIN_MAP.encoderB, (state & 2) !== 0);
  for (let k = 1; k <= Math.abs(counts); k++) {
    const at = startNanos + k * spacing;
    if (skipped.has(k) && k < Math.abs(counts)) {
      count += 2 * step;
      k++;
      const next = GRAY[((count % 4) + 4) % 4];
      const changed = state ^ next;
      if (changed & 1) clock.schedule(at, PIN_MAP.encoderA, (next & 1) !== 0);
      if (changed & 2) clock.schedule(at, PIN_MAP.encoderB, (next & 2) !== 0);
      state = next;
      continue;
    }
    count += step;
    const next = GRAY[((count % 4) + 4) % 4];
    const changed = state ^ next;
    clock.schedule(at, changed & 1 ? PIN_MAP.encoderA : PIN_MAP.encoderB, (changed & 1 ? next : next >> 1) % 2 === 1);
    state = next;
  }
  return startNanos + Math.abs(counts) * spacing;
}

/** The step/direction pins (firmware/src/rp2040/pins.h): STEP and DIR from the step
 * generator's PIO block, the driver's enable (active low) from SIO. */
export const STEPPER_PINS = { step: 18, dir: 19, enable: 20 };

/** The Python device's simulated stepper at power-up (calls 45 and 47: a NEMA 17, 2 A,
 * 0.59 N m, at 16 microsteps) with a NEMA 17 rotor's inertia and a 1000-line encoder. */
export const DEFAULT_STEPPER = {
  fullSteps: 200,
  microsteps: 16,
  holdingNm: 0.59,
  detentNm: 0.02,
  cornerRpm: 760,
  inertiaKgM2: 1e-5,
  viscousNmPerRadS: 0,
  loadNm: 0,
  countsPerRevolution: 4000,
  stepNanos: 1000,
};

/**
 * A hybrid stepper on a step/direction driver, outside the chip: the field follows the STEP
 * pin's rising edges (a microstep each, up with DIR high), at the time each came, while the
 * driver's enable is low; the rotor (the model of usbmotion.device.stepper, in binary64:
 * the field's pull T_a sin(2 pi (field - theta) / 4u), its torque falling as 1/speed above
 * the corner speed, the detent -T_d sin(2 pi theta / u), viscous and Coulomb friction, a
 * velocity that would reverse within an integration step stopping there) integrated by
 * semi-implicit Euler in steps of `stepNanos`; its quadrature encoder's A/B pins driven at
 * each count it crosses (the decoder's pins, as MotorWorld drives them). It runs on the
 * timer's time (the step edges' clock), standing still while the timer is held.
 */
export class StepperWorld {
  /**
   * @param {PioClock} clock
   * @param {object} mcu
   * @param {object} options DEFAULT_STEPPER's keys, `startCount` (the encoder's count
   *   at power-up, 0), and `absolute`: an absolute encoder (AbsolutePwm, its options) whose
   *   PWM drives channel A instead of the quadrature
   */
  constructor(clock, mcu, options = {}) {
    const extra = ['startCount', 'absolute'];
    for (const key of Object.keys(options)) {
      if (!(key in DEFAULT_STEPPER) && !extra.includes(key)) {
        throw new Error(`stepper option ${JSON.stringify(key)} is unknown; known: `
          + `${[...Object.keys(DEFAULT_STEPPER), ...extra].join(', ')}`);
      }
    }
    const m = { ...DEFAULT_STEPPER, ...options };
    for (const key of ['fullSteps', 'microsteps', 'holdingNm', 'cornerRpm', 'inertiaKgM2',
      'countsPerRevolution', 'stepNanos']) {
      if (!(typeof m[key] === 'number' && m[key] > 0)) {
        throw new Error(`stepper ${key} ${JSON.stringify(m[key])} must be a number above 0`);
      }
    }
    this.clock = clock;
    this.mcu = mcu;
    this.m = m;
    this.perRevolution = m.fullSteps * m.microsteps;
    this.radPerMicrostep = (2 * Math.PI) / this.perRevolution;
    this.cornerPerS = (m.cornerRpm * this.perRevolution) / 60;
    this.theta = 0; // microsteps
    this.omega = 0; // microsteps/s
    this.field = 0; // the steps the driver took
    this.steps = 0; // rising edges seen
    this.pending = []; // [timerNanos, +1 | -1]
    this.direction = 1;
    this.time = null; // timer ns integrated up to
    this.count = (options.startCount ?? 0);
    this.countBase = this.count;
    this.edgesEmitted = 0;
    clock.drive(PIN_MAP.encoderA, PIN_MAP.encoderB);
    this.pwm = options.absolute
      ? new AbsolutePwm(clock, () => this.turnsAt(), options.absolute) : null;
    if (!this.pwm) {
      const state = GRAY[((this.count % 4) + 4) % 4];
      mcu.gpio[PIN_MAP.encoderA].setInputValue((state & 1) !== 0);
      mcu.gpio[PIN_MAP.encoderB].setInputValue((state & 2) !== 0);
    }
    clock.edgeListeners.push((pin, level, nanos) => {
      if (pin === STEPPER_PINS.dir) {
        this.direction = level ? 1 : -1;
      } else if (pin === STEPPER_PINS.step && level === 1) {
        this.steps++;
        this.pending.push([nanos, this.direction]);
      }
    });
  }

  /** The shaft's angle in turns, from where the count started (startCount's turns on). */
  turnsAt() {
    return this.countBase / this.m.countsPerRevolution + this.theta / this.perRevolution;
  }

  /** The driver's enable pin low (active): the field pulls. */
  get powered() {
    const pin = this.mcu.gpio[STEPPER_PINS.enable];
    return pin.outputEnable && !pin.outputValue;
  }

  /** Integrates the rotor over [fromNanos, toNanos) of clock time (the timer's, less its
   * lag: `timerFrom` .. `timerTo`), and schedules the encoder's pins. */
  advance(fromNanos, toNanos, timerFrom, timerTo) {
    if (this.time === null || this.time < timerFrom) {
      this.time = timerFrom;
    }
    const m = this.m;
    const h = m.stepNanos;
    const powered = this.powered;
    while (this.time < timerTo) {
      const until = Math.min(this.time + h, timerTo);
      // steps up to the end of this step (those that came late, at its start)
      while (this.pending.length > 0 && this.pending[0][0] < until) {
        this.field += this.pending.shift()[1];
      }
      const dt = (until - this.time) / 1e9;
      const speed = Math.abs(this.omega);
      const available = speed <= this.cornerPerS ? m.holdingNm : (m.holdingNm * this.cornerPerS) / speed;
      const pull = powered
        ? available * Math.sin((2 * Math.PI * (this.field - this.theta)) / (4 * m.microsteps)) : 0;
      const torque = pull - m.detentNm * Math.sin((2 * Math.PI * this.theta) / m.microsteps);
      let net;
      if (this.omega === 0) {
        net = Math.abs(torque) <= m.loadNm ? 0 : torque - Math.sign(torque) * m.loadNm;
      } else {
        net = torque - m.viscousNmPerRadS * this.omega * this.radPerMicrostep
          - Math.sign(this.omega) * m.loadNm;
      }
      let omega = this.omega + (net / m.inertiaKgM2 / this.radPerMicrostep) * dt;
      if ((this.omega > 0 && omega < 0) || (this.omega < 0 && omega > 0)) {
        omega = 0;
      }
      const before = this.theta;
      this.theta += omega * dt;
      this.omega = omega;
      this.emitCounts(before, this.theta, this.time, until, fromNanos - timerFrom);
      this.time = until;
    }
  }

  /** The encoder's count at `theta` microsteps: floor(theta x counts per revolution / per
   * revolution). */
  countAt(theta) {
    return this.countBase + Math.floor((theta * this.m.countsPerRevolution) / this.perRevolution);
  }

  emitCounts(from, to, timerFrom, timerTo, lag) {
    const target = this.countAt(to);
    while (this.count !== target) {
      const next = target > this.count ? this.count + 1 : this.count - 1;
      const boundary = ((target > this.count ? next : this.count) - this.countBase)
        * this.perRevolution / this.m.countsPerRevolution;
      const fraction = to === from ? 0 : Math.min(Math.max((boundary - from) / (to - from), 0), 1);
      const at = timerFrom + fraction * (timerTo - timerFrom) + lag;
      const before = GRAY[((this.count % 4) + 4) % 4];
      const after = GRAY[((next % 4) + 4) % 4];
      const changed = before ^ after;
      const pin = changed & 1 ? PIN_MAP.encoderA : PIN_MAP.encoderB;
      if (!this.pwm) {
        this.clock.schedule(at, pin, ((changed & 1 ? after : after >> 1) & 1) !== 0);
      }
      this.edgesEmitted++;
      this.count = next;
    }
  }

  /** What the world holds, for the tests. */
  get state() {
    return {
      theta: this.theta,
      omega: this.omega,
      field: this.field,
      steps: this.steps,
      count: this.count,
      powered: this.powered,
      edges: this.edgesEmitted,
      pwm: this.pwm ? this.pwm.state : null,
    };
  }
}
