// What the RP2040 has and rp2040js 1.4.1 lacks, added from outside the package: the second
// Cortex-M0+ core (started at the bootrom's reset vector, as on the chip), per-core CPUID, the
// two inter-core FIFOs with their status bits and SIO_IRQ_PROC0/1, a hardware divider and
// interpolators per core, SEV waking the other core's WFE, PSM FRCE_OFF.PROC1 holding core1
// in reset, and the peripheral interrupts raised in both cores' NVICs.
//
// Properties are only ever assigned, never redefined: Object.defineProperty on the RP2040
// object puts V8 into dictionary mode and halves the emulator's speed.

import { RP2040 } from 'rp2040js';

const SIO_CPUID = 0x000;
const SIO_FIFO_ST = 0x050;
const SIO_FIFO_WR = 0x054;
const SIO_FIFO_RD = 0x058;
const FIFO_DEPTH = 8;
const FIFO_ST_VLD = 1 << 0;
const FIFO_ST_RDY = 1 << 1;
const FIFO_ST_WOF = 1 << 2;
const FIFO_ST_ROE = 1 << 3;
const IRQ_SIO_PROC0 = 15;
const IRQ_SIO_PROC1 = 16;
const PSM_BASE_KEY = 0x40010;
const PSM_FRCE_OFF = 0x04;
const PSM_PROC1 = 1 << 16;

/** A core-to-core mailbox: 8 words deep. */
class Mailbox {
  constructor() {
    this.words = new Uint32Array(FIFO_DEPTH);
    this.start = 0;
    this.count = 0;
  }
  push(value) {
    this.words[(this.start + this.count) % FIFO_DEPTH] = value;
    this.count++;
  }
  pull() {
    const value = this.words[this.start];
    this.start = (this.start + 1) % FIFO_DEPTH;
    this.count--;
    return value;
  }
}

const sioClasses = new Map();

/** The SIO with what differs per core, derived from the package's own SIO class. */
function dualSioClass(BaseSio) {
  let Class = sioClasses.get(BaseSio);
  if (Class) {
    return Class;
  }
  Class = class DualSio extends BaseSio {
    constructor(rp2040) {
      super(rp2040);
      // mailbox[n] is core n's receive FIFO (written by the other core)
      this.mailbox = [new Mailbox(), new Mailbox()];
      this.sticky = [0, 0]; // WOF | ROE per core
    }
    readUint32(offset) {
      switch (offset) {
        case SIO_CPUID:
          return this.rp2040.coreIndex;
        case SIO_FIFO_ST:
          return this.fifoStatus(this.rp2040.coreIndex);
        case SIO_FIFO_RD: {
          const core = this.rp2040.coreIndex;
          const mailbox = this.mailbox[core];
          let value = 0;
          if (mailbox.count === 0) {
            this.sticky[core] |= FIFO_ST_ROE;
          } else {
            value = mailbox.pull();
          }
          this.updateFifoIrq(core);
          return value;
        }
        case SIO_FIFO_WR:
          return 0;
      }
      return super.readUint32(offset);
    }
    writeUint32(offset, value) {
      switch (offset) {
        case SIO_FIFO_ST: {
          const core = this.rp2040.coreIndex;
          this.sticky[core] &= ~(value & (FIFO_ST_WOF | FIFO_ST_ROE));
          this.updateFifoIrq(core);
          return;
        }
        case SIO_FIFO_WR: {
          const core = this.rp2040.coreIndex;
          const other = this.mailbox[1 - core];
          if (other.count === FIFO_DEPTH) {
            this.sticky[core] |= FIFO_ST_WOF;
            this.updateFifoIrq(core);
          } else {
            other.push(value >>> 0);
            this.updateFifoIrq(1 - core);
          }
          return;
        }
        case SIO_FIFO_RD:
          return;
      }
      super.writeUint32(offset, value);
    }
    fifoStatus(core) {
      return (
        (this.mailbox[core].count > 0 ? FIFO_ST_VLD : 0) |
        (this.mailbox[1 - core].count < FIFO_DEPTH ? FIFO_ST_RDY : 0) |
        this.sticky[core]
      );
    }
    updateFifoIrq(core) {
      const level = this.mailbox[core].count > 0 || this.sticky[core] !== 0;
      this.rp2040.cores[core].setInterrupt(core === 0 ? IRQ_SIO_PROC0 : IRQ_SIO_PROC1, level);
    }
  };
  sioClasses.set(BaseSio, Class);
  return Class;
}

/** The divider and interpolator state the SIO holds for the core that runs. */
function saveCoreLocal(sio, slot) {
  slot.divDividend = sio.divDividend;
  slot.divDivisor = sio.divDivisor;
  slot.divQuotient = sio.divQuotient;
  slot.divRemainder = sio.divRemainder;
  slot.divCSR = sio.divCSR;
  slot.interp0 = sio.interp0;
  slot.interp1 = sio.interp1;
}

function loadCoreLocal(sio, slot) {
  sio.divDividend = slot.divDividend;
  sio.divDivisor = slot.divDivisor;
  sio.divQuotient = slot.divQuotient;
  sio.divRemainder = slot.divRemainder;
  sio.divCSR = slot.divCSR;
  sio.interp0 = slot.interp0;
  sio.interp1 = slot.interp1;
}

/**
 * An RP2040 with both cores. `core` is the core executing at the moment (the package's
 * peripherals reach the core's private state through it); `select(n)` switches.
 */
export class DualRP2040 extends RP2040 {
  constructor(clock) {
    super(clock);
    const CoreClass = this.core.constructor;
    this.CoreClass = CoreClass;
    this.coreIndex = 0;
    this.cores = [this.core, new CoreClass(this)];
    this.core1Off = false;
    this.retiredCycles = [0, 0]; // cycles of core1 objects replaced by a reset
    const Sio = dualSioClass(this.sio.constructor);
    this.sio = new Sio(this);
    this.coreLocal = [{}, {}];
    saveCoreLocal(this.sio, this.coreLocal[0]);
    loadCoreLocal(this.sio, this.coreLocal[0]);
    // core1's divider and interpolators start as fresh ones
    const fresh = new Sio(this);
    saveCoreLocal(fresh, this.coreLocal[1]);
    const psm = this.peripherals[PSM_BASE_KEY];
    const psmWrite = psm.writeUint32.bind(psm);
    psm.writeUint32 = (offset, value) => {
      psmWrite(offset, value);
      if (offset === PSM_FRCE_OFF) {
        this.setCore1Power(!(psm.frceOff & PSM_PROC1));
      }
    };
    this.warnings = [];
    this.onWarning = (source, message) => {
      if (this.warnings.length < 100) {
        this.warnings.push(`${source}: ${message}`);
      }
    };
    this.logger = {
      debug() {},
      info: (source, message) => {
        if (message === 'SEV') {
          this.sendEvent();
        }
      },
      warn: (source, message) => this.onWarning(source, message),
      error: (source, message) => this.onWarning(source, message),
    };
  }

  /** Makes core `index` the executing one. */
  select(index) {
    if (index !== this.coreIndex) {
      saveCoreLocal(this.sio, this.coreLocal[this.coreIndex]);
      loadCoreLocal(this.sio, this.coreLocal[index]);
      this.coreIndex = index;
      this.core = this.cores[index];
    }
  }

  /** SEV: sets the event register of both cores and wakes a core sleeping in WFE. */
  sendEvent() {
    for (let index = 0; index < 2; index++) {
      const core = this.cores[index];
      if (index !== this.coreIndex && core.waiting) {
        core.waiting = false;
      } else {
        core.eventRegistered = true;
      }
    }
  }

  setCore1Power(on) {
    if (!on) {
      this.core1Off = true;
    } else if (this.core1Off) {
      this.core1Off = false;
      // out of reset: a new core, from the bootrom's reset vector
      this.retiredCycles[1] += this.cores[1].cycles;
      const core = new this.CoreClass(this);
      core.reset();
      this.cores[1] = core;
      if (this.coreIndex === 1) {
        this.core = core;
      }
      saveCoreLocal(new this.sio.constructor(this), this.coreLocal[1]);
    }
  }

  /** Cycles each core executed (not counting sleep) since the chip was made. */
  busyCycles() {
    return [this.retiredCycles[0] + this.cores[0].cycles, this.retiredCycles[1] + this.cores[1].cycles];
  }

  reset() {
    super.reset();
    if (this.cores) {
      this.cores[1].reset();
    }
  }

  setInterrupt(irq, value) {
    if (!this.cores) {
      super.setInterrupt(irq, value);
    } else if (irq === IRQ_SIO_PROC0) {
      this.cores[0].setInterrupt(irq, value);
    } else if (irq === IRQ_SIO_PROC1) {
      this.cores[1].setInterrupt(irq, value);
    } else {
      this.cores[0].setInterrupt(irq, value);
      this.cores[1].setInterrupt(irq, value);
    }
  }
}
