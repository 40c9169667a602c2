// UF2 images (Microsoft's USB flashing format, as the RP2040 bootloader takes them): 512-byte
// blocks, each carrying up to 476 bytes for one target address.

const BLOCK_BYTES = 512;
const MAGIC_START0 = 0x0a324655;
const MAGIC_START1 = 0x9e5d5157;
const MAGIC_END = 0x0ab16f30;
const FLAG_NOT_MAIN_FLASH = 0x00000001;
const FLAG_FAMILY_ID_PRESENT = 0x00002000;
export const RP2040_FAMILY_ID = 0xe48bff56;

/**
 * Parses a UF2 image into its payloads.
 * @param {Uint8Array} bytes the whole file
 * @param {number} [familyId] blocks of another family are skipped
 * @returns {{address: number, data: Uint8Array}[]}
 */
export function parseUf2(bytes, familyId = RP2040_FAMILY_ID) {
  if (bytes.length === 0 || bytes.length % BLOCK_BYTES !== 0) {
    throw new Error(`UF2 image of ${bytes.length} bytes: not a whole number of 512-byte blocks`);
  }
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const payloads = [];
  for (let offset = 0; offset < bytes.length; offset += BLOCK_BYTES) {
    const block = offset / BLOCK_BYTES;
    if (
      view.getUint32(offset, true) !== MAGIC_START0 ||
      view.getUint32(offset + 4, true) !== MAGIC_START1 ||
      view.getUint32(offset + BLOCK_BYTES - 4, true) !== MAGIC_END
    ) {
      throw new Error(`UF2 block ${block}: bad magic numbers`);
    }
    const flags = view.getUint32(offset + 8, true);
    const address = view.getUint32(offset + 12, true);
    const size = view.getUint32(offset + 16, true);
    const family = view.getUint32(offset + 28, true);
    if (size > 476) {
      throw new Error(`UF2 block ${block}: payload of ${size} bytes; at most 476`);
    }
    if (flags & FLAG_NOT_MAIN_FLASH) {
      continue;
    }
    if (flags & FLAG_FAMILY_ID_PRESENT && family !== familyId) {
      continue;
    }
    payloads.push({ address, data: bytes.slice(offset + 32, offset + 32 + size) });
  }
  if (payloads.length === 0) {
    throw new Error('UF2 image has no block for the RP2040 main flash');
  }
  return payloads;
}
