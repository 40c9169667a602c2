// The executed path: a wide line through the measured positions, each segment coloured by
// the size of the following error at its ends. Grows by appending into preallocated buffers
// (one upload of a few floats per push), so a long run costs no more per push than a short one.

import { Color } from 'three';
import { LineMaterial } from 'three/examples/jsm/lines/LineMaterial.js';
import { LineSegments2 } from 'three/examples/jsm/lines/LineSegments2.js';
import { LineSegmentsGeometry } from 'three/examples/jsm/lines/LineSegmentsGeometry.js';

const FIRST_CAPACITY = 4096;
// Past this many segments the older half is dropped: a long run's trail would otherwise
// grow without end.
const MAX_SEGMENTS = 1 << 20;
// A new point only when the tool moved at least this far (mm), so a machine at rest adds
// nothing.
const MIN_STEP_MM = 0.001;
const WIDTH_PX = 3;

// The error colour scale: green at 0, yellow at half the scale, red at the scale and above.
// The legend's bar in style.css uses the same three colours.
const SCALE_STOPS = [new Color(0x1f9d3a), new Color(0xe0b400), new Color(0xd62020)];

export function errorColour(errorMm, scaleMm, target) {
  const position = Math.min(Math.max(errorMm / scaleMm, 0), 1) * 2;
  const index = Math.min(Math.floor(position), 1);
  return target.lerpColors(SCALE_STOPS[index], SCALE_STOPS[index + 1], position - index);
}

export class Trail {
  constructor(scene, { renderOrder }) {
    this.scene = scene;
    this.renderOrder = renderOrder;
    this.material = new LineMaterial({ vertexColors: true, linewidth: WIDTH_PX, depthTest: false });
    this.scaleMm = 0.05;
    this.segments = 0;
    this.last = null;
    this.line = null;
    this.allocate(FIRST_CAPACITY);
  }

  // Buffers for `capacity` segments, the segments so far copied over. `errors` holds each
  // segment's two ends' errors, for colouring again when the scale changes.
  allocate(capacity) {
    const positions = new Float32Array(capacity * 6);
    const colours = new Float32Array(capacity * 6);
    const errors = new Float32Array(capacity * 2);
    if (this.line) {
      positions.set(this.positions.array.subarray(0, this.segments * 6));
      colours.set(this.colours.array.subarray(0, this.segments * 6));
      errors.set(this.errors.subarray(0, this.segments * 2));
      this.line.geometry.dispose();
      this.scene.remove(this.line);
    }
    const geometry = new LineSegmentsGeometry().setPositions(positions).setColors(colours);
    this.positions = geometry.attributes.instanceStart.data;
    this.colours = geometry.attributes.instanceColorStart.data;
    this.errors = errors;
    geometry.instanceCount = this.segments;
    this.line = new LineSegments2(geometry, this.material);
    this.line.frustumCulled = false;
    this.line.renderOrder = this.renderOrder;
    this.scene.add(this.line);
  }

  // A measured point and the size of the error there; false when it was too close to the
  // last one to draw.
  add(point, errorMm) {
    const last = this.last;
    if (last && Math.hypot(point[0] - last.point[0], point[1] - last.point[1],
      point[2] - last.point[2]) < MIN_STEP_MM) {
      return false;
    }
    this.last = { point, errorMm };
    if (!last) {
      return true;
    }
    if (this.segments * 6 === this.positions.array.length) {
      if (this.segments >= MAX_SEGMENTS) {
        this.dropOlderHalf();
      } else {
        this.allocate(this.segments * 2);
      }
    }
    const index = this.segments;
    this.positions.array.set([...last.point, ...point], index * 6);
    this.errors.set([last.errorMm, errorMm], index * 2);
    this.paint(index);
    this.positions.addUpdateRange(index * 6, 6);
    this.colours.addUpdateRange(index * 6, 6);
    this.positions.needsUpdate = true;
    this.colours.needsUpdate = true;
    this.segments += 1;
    this.line.geometry.instanceCount = this.segments;
    return true;
  }

  paint(index) {
    const start = errorColour(this.errors[index * 2], this.scaleMm, new Color());
    const end = errorColour(this.errors[index * 2 + 1], this.scaleMm, new Color());
    this.colours.array.set([start.r, start.g, start.b, end.r, end.g, end.b], index * 6);
  }

  dropOlderHalf() {
    const keep = this.segments >> 1;
    const from = this.segments - keep;
    this.positions.array.copyWithin(0, from * 6, this.segments * 6);
    this.colours.array.copyWithin(0, from * 6, this.segments * 6);
    this.errors.copyWithin(0, from * 2, this.segments * 2);
    this.segments = keep;
    this.line.geometry.instanceCount = keep;
    this.uploadAll();
  }

  uploadAll() {
    for (const buffer of [this.positions, this.colours]) {
      buffer.clearUpdateRanges();
      buffer.needsUpdate = true;
    }
  }

  clear() {
    this.segments = 0;
    this.last = null;
    this.line.geometry.instanceCount = 0;
  }

  setScale(scaleMm) {
    this.scaleMm = scaleMm;
    for (let index = 0; index < this.segments; index += 1) {
      this.paint(index);
    }
    this.uploadAll();
  }
}
