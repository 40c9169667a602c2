// The symbol table of a 32-bit little-endian ELF file (the firmware's .elf), read by name.

const SHT_SYMTAB = 2;
/** A symbol's type (the low nibble of st_info): a function. */
export const STT_FUNC = 2;

/**
 * Reads the symbols of an ELF32 file.
 * @param {Uint8Array} bytes the whole file
 * @returns {Map<string, {address: number, size: number, type: number}>}
 */
export function readElfSymbols(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (view.getUint32(0, false) !== 0x7f454c46) {
    throw new Error('not an ELF file');
  }
  if (bytes[4] !== 1 || bytes[5] !== 1) {
    throw new Error('not a 32-bit little-endian ELF file');
  }
  const sectionOffset = view.getUint32(0x20, true);
  const sectionSize = view.getUint16(0x2e, true);
  const sectionCount = view.getUint16(0x30, true);
  const section = (index) => {
    const at = sectionOffset + index * sectionSize;
    return {
      type: view.getUint32(at + 4, true),
      offset: view.getUint32(at + 16, true),
      size: view.getUint32(at + 20, true),
      link: view.getUint32(at + 24, true),
      entrySize: view.getUint32(at + 36, true),
    };
  };
  const decoder = new TextDecoder('latin1');
  const symbols = new Map();
  for (let index = 0; index < sectionCount; index++) {
    const table = section(index);
    if (table.type !== SHT_SYMTAB) {
      continue;
    }
    const strings = section(table.link);
    for (let at = table.offset; at + 16 <= table.offset + table.size; at += table.entrySize || 16) {
      const nameOffset = strings.offset + view.getUint32(at, true);
      let end = nameOffset;
      while (end < bytes.length && bytes[end] !== 0) {
        end++;
      }
      const name = decoder.decode(bytes.subarray(nameOffset, end));
      if (name && !symbols.has(name)) {
        symbols.set(name, {
          address: view.getUint32(at + 4, true),
          size: view.getUint32(at + 8, true),
          type: bytes[at + 12] & 0xf,
        });
      }
    }
  }
  return symbols;
}
