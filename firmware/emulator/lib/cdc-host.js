// The USB host's side of the CDC serial port: the package's USBCDC helper enumerates the
// device and receives its output; host-to-device bytes are queued here and an OUT transfer the
// device arms is answered only when there is data (a real host NAKs until then). Answering at
// once with empty packets, as the helper does, keeps an idle core0 busy in USB interrupts.

import { USBCDC } from 'rp2040js';

export class CdcHost {
  /**
   * @param {import('rp2040js').RPUSBController} usb
   * @param {(data: Uint8Array) => void} onData device output
   */
  constructor(usb, onData) {
    this.usb = usb;
    this.cdc = new USBCDC(usb);
    this.connected = false;
    this.pending = []; // Uint8Array chunks not yet given to the device
    this.pendingBytes = 0;
    this.heldRead = 0; // size of an armed OUT transfer waiting for data, 0 if none
    this.onConnected = null;
    this.cdc.onDeviceConnected = () => {
      this.connected = true;
      this.onConnected?.();
    };
    this.cdc.onSerialData = onData;
    usb.onEndpointRead = (endpoint, size) => {
      if (endpoint !== this.cdc.outEndpoint) {
        return;
      }
      if (this.pendingBytes > 0) {
        this.answerRead(size);
      } else {
        this.heldRead = size;
      }
    };
  }

  /** Queues bytes for the device. */
  send(data) {
    if (data.length === 0) {
      return;
    }
    this.pending.push(Uint8Array.from(data));
    this.pendingBytes += data.length;
    if (this.heldRead > 0) {
      const size = this.heldRead;
      this.heldRead = 0;
      this.answerRead(size);
    }
  }

  answerRead(size) {
    const packet = new Uint8Array(Math.min(size, this.pendingBytes));
    let filled = 0;
    while (filled < packet.length) {
      const chunk = this.pending[0];
      const take = Math.min(chunk.length, packet.length - filled);
      packet.set(chunk.subarray(0, take), filled);
      filled += take;
      if (take === chunk.length) {
        this.pending.shift();
      } else {
        this.pending[0] = chunk.subarray(take);
      }
    }
    this.pendingBytes -= packet.length;
    this.usb.endpointReadDone(this.cdc.outEndpoint, packet);
  }

  /** Bytes given to the host but not yet taken by the device. */
  get queuedBytes() {
    return this.pendingBytes;
  }
}
