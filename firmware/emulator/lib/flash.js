// The flash chip: the firmware image plus whatever the firmware programs, kept in a file so
// flash variables survive power cycles and emulator restarts.
//
// rp2040js's SSI cannot erase or program, so the bootrom's flash functions are answered here:
// each begins with a breakpoint (see bootrom.js), and the breakpoint does the function's work
// on the flash bytes and returns to the caller. Flash timing is not modelled.

import { existsSync, readFileSync, renameSync, writeFileSync } from 'node:fs';

export const FLASH_BYTES = 2 * 1024 * 1024; // the Pico's W25Q16JV
export const SECTOR_BYTES = 4096;
export const PAGE_BYTES = 256;
const XIP_BASE = 0x10000000;

export class FlashImage {
  /**
   * @param {string|null} path the file holding the flash contents, or null for none
   */
  constructor(path) {
    this.path = path;
    this.bytes = new Uint8Array(FLASH_BYTES).fill(0xff);
    this.program = [];
    if (path && existsSync(path)) {
      const stored = readFileSync(path);
      if (stored.length !== FLASH_BYTES) {
        throw new Error(`flash file ${path} has ${stored.length} bytes; expected ${FLASH_BYTES}`);
      }
      this.bytes.set(stored);
    }
  }

  /** Writes a UF2's payloads over the flash, as the bootloader does; the rest is kept. */
  flashUf2(payloads) {
    this.program = payloads;
    this.writePayloads();
    this.persist();
  }

  writePayloads() {
    for (const { address, data } of this.program) {
      const offset = address - XIP_BASE;
      if (offset < 0 || offset + data.length > FLASH_BYTES) {
        throw new Error(`UF2 block at 0x${address.toString(16)} lies outside the flash`);
      }
      this.bytes.set(data, offset);
    }
  }

  /** Erases everything but the program: the flash as freshly loaded with the UF2. */
  resetData() {
    this.bytes.fill(0xff);
    this.writePayloads();
    this.persist();
  }

  erase(offset, count) {
    const start = Math.floor(offset / SECTOR_BYTES) * SECTOR_BYTES;
    const end = Math.min(FLASH_BYTES, Math.ceil((offset + count) / SECTOR_BYTES) * SECTOR_BYTES);
    this.bytes.fill(0xff, start, end);
    return [start, end];
  }

  /** NOR programming: bits only go from 1 to 0. */
  programBytes(offset, data) {
    for (let i = 0; i < data.length && offset + i < FLASH_BYTES; i++) {
      this.bytes[offset + i] &= data[i];
    }
  }

  persist() {
    if (this.path) {
      const temporary = `${this.path}.tmp`;
      writeFileSync(temporary, this.bytes);
      renameSync(temporary, this.path);
    }
  }
}

/** Breakpoint numbers of the bootrom functions the emulator answers. */
export const FLASH_BREAKPOINTS = new Map([
  ['IF', 0xa0], // connect_internal_flash
  ['EX', 0xa1], // flash_exit_xip
  ['RE', 0xa2], // flash_range_erase(addr, count, block_size, block_cmd)
  ['RP', 0xa3], // flash_range_program(addr, data, count)
  ['FC', 0xa4], // flash_flush_cache
  ['CX', 0xa5], // flash_enter_cmd_xip
]);

/**
 * Answers a flash-function breakpoint on the executing core; returns false for any other.
 * @param {import('./dual-core.js').DualRP2040} mcu
 * @param {FlashImage} flash
 * @param {Map<number, string>} byNumber breakpoint number -> function code
 */
export function answerFlashBreakpoint(mcu, flash, byNumber, number) {
  const name = byNumber.get(number);
  if (name === undefined) {
    return false;
  }
  const core = mcu.core;
  const [r0, r1, r2] = core.registers;
  if (name === 'RE') {
    const [start, end] = flash.erase(r0, r1);
    mcu.flash.fill(0xff, start, end);
    flash.persist();
  } else if (name === 'RP') {
    const data = new Uint8Array(r2);
    for (let i = 0; i < r2; i++) {
      data[i] = mcu.readUint8(r1 + i);
    }
    flash.programBytes(r0, data);
    mcu.flash.set(flash.bytes.subarray(r0, Math.min(FLASH_BYTES, r0 + r2)), r0);
    flash.persist();
  }
  core.PC = core.LR & ~1; // return to the caller
  return true;
}
