// The USB host's side of the CDC serial port: the package's USBCDC helper enumerates the
// device and receives its output; host-to-device bytes are queued here and an OUT transfer the
// device arms is answered only when there is data (a real host NAKs until then). Answering at
// once with empty packets, as the helper does, keeps an idle core0 busy in USB interrupts.
//
// The host also sends a start-of-frame packet every millisecond, which the package does not
// model in device mode: the controller's DEV_SOF interrupt and its SOF_RD frame number (read
// to clear the interrupt). TinyUSB needs them on the RP2040: its workaround of erratum
// RP2040-E15 holds back a bulk IN transfer started in the last 200 us of a frame until the
// next SOF, with the SOF interrupt enabled while a bulk IN endpoint is busy. The SOFs are only
// scheduled while the device enables that interrupt (a real host sends them anyway; the
// device does not see them then), so an idle device has no pending clock event.

import { USBCDC } from 'rp2040js';

const SOF_RD = 0x048;
const INTR_DEV_SOF = 1 << 17;
const FRAME_NS = 1e6;
const FRAME_NUMBER_MASK = 0x7ff;

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
    this.setUpStartOfFrame(usb);
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

  setUpStartOfFrame(usb) {
    const clock = usb.rp2040.clock;
    this.clock = clock;
    this.sofScheduled = false;
    this.sofAlarm = clock.createAlarm(() => {
      this.sofScheduled = false;
      usb.intRaw |= INTR_DEV_SOF;
      usb.checkInterrupts();
      this.scheduleStartOfFrame();
    });
    const read = usb.readUint32.bind(usb);
    usb.readUint32 = (offset) => {
      if (offset === SOF_RD) {
        usb.intRaw &= ~INTR_DEV_SOF;
        usb.checkInterrupts();
        return this.frameNumber;
      }
      return read(offset);
    };
    const write = usb.writeUint32.bind(usb);
    usb.writeUint32 = (offset, value) => {
      write(offset, value);
      this.scheduleStartOfFrame();
    };
  }

  /** The frame the host is in: one per millisecond of emulated time. */
  get frameNumber() {
    return Math.floor(this.clock.nanos / FRAME_NS) & FRAME_NUMBER_MASK;
  }

  /** The next SOF at the next frame boundary, while the device enables the SOF interrupt. */
  scheduleStartOfFrame() {
    const wanted = (this.usb.intEnable & INTR_DEV_SOF) !== 0;
    if (wanted && !this.sofScheduled) {
      this.sofScheduled = true;
      this.sofAlarm.schedule(FRAME_NS - (this.clock.nanos % FRAME_NS));
    } else if (!wanted && this.sofScheduled) {
      this.sofScheduled = false;
      this.sofAlarm.cancel();
    }
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
