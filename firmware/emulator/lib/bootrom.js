// The RP2040 bootrom: loading it, finding its public functions through the ROM table, and
// replacing the flash functions' first instruction by a breakpoint the emulator answers.

import { readFileSync } from 'node:fs';
import { dirname, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

const here = dirname(fileURLToPath(import.meta.url));
/** The shared copy beside the project: ../shared/rp2040/bootrom/b1.bin */
export const DEFAULT_BOOTROM_PATH = resolve(here, '../../../../shared/rp2040/bootrom/b1.bin');

const FUNC_TABLE_POINTER = 0x14;
const BOOTROM_BYTES = 16384;

export function romCode(name) {
  return name.charCodeAt(0) | (name.charCodeAt(1) << 8);
}

/**
 * @param {string} [path]
 * @returns {Uint8Array} the 16 KiB image
 */
export function readBootrom(path = process.env.USBMOTION_BOOTROM || DEFAULT_BOOTROM_PATH) {
  let bytes;
  try {
    bytes = new Uint8Array(readFileSync(path));
  } catch (error) {
    throw new Error(`no RP2040 bootrom at ${path} (${error.code}); pass --bootrom or set USBMOTION_BOOTROM`);
  }
  if (bytes.length !== BOOTROM_BYTES) {
    throw new Error(`bootrom ${path} has ${bytes.length} bytes; an RP2040 bootrom has ${BOOTROM_BYTES}`);
  }
  return bytes;
}

/**
 * The address of each public function, by its two-letter code ('RE', 'RP', ...).
 * @param {Uint8Array} image
 * @returns {Map<string, number>} addresses with the Thumb bit cleared
 */
export function romFunctions(image) {
  const view = new DataView(image.buffer, image.byteOffset, image.byteLength);
  const functions = new Map();
  for (let at = view.getUint16(FUNC_TABLE_POINTER, true); at + 4 <= image.length; at += 4) {
    const code = view.getUint16(at, true);
    if (code === 0) {
      break;
    }
    const name = String.fromCharCode(code & 0xff, code >> 8);
    functions.set(name, view.getUint16(at + 2, true) & ~1);
  }
  return functions;
}

/**
 * A copy of the image whose listed functions each begin with BKPT #code.
 * @param {Uint8Array} image
 * @param {Map<string, number>} breakpoints function code -> breakpoint number (0-255)
 * @returns {{image: Uint8Array, byAddress: Map<number, string>}}
 */
export function patchBootrom(image, breakpoints) {
  const functions = romFunctions(image);
  const patched = image.slice();
  const view = new DataView(patched.buffer);
  const byAddress = new Map();
  for (const [name, number] of breakpoints) {
    const address = functions.get(name);
    if (address === undefined) {
      throw new Error(`bootrom has no function '${name}' in its ROM table`);
    }
    view.setUint16(address, 0xbe00 | number, true);
    byAddress.set(number, name);
  }
  return { image: patched, byAddress };
}
