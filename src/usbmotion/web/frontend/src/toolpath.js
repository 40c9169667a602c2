// The toolpath view (three.js): the planned path of the open program, the path the machine
// executed over it coloured by the size of the following error, the segments of the line
// executing now, and the tool. Machine coordinates in mm, Z up.

import {
  AxesHelper, Box3, BufferGeometry, Color, Float32BufferAttribute, GridHelper, Group,
  LineBasicMaterial, LineDashedMaterial, LineSegments, Mesh, MeshBasicMaterial,
  OrthographicCamera, Scene, SphereGeometry, Vector3, WebGLRenderer,
} from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';
import { LineMaterial } from 'three/examples/jsm/lines/LineMaterial.js';
import { LineSegments2 } from 'three/examples/jsm/lines/LineSegments2.js';
import { LineSegmentsGeometry } from 'three/examples/jsm/lines/LineSegmentsGeometry.js';
import { Trail } from './trail.js';

const COLOURS = {
  background: 0xfbfbf8,
  feed: 0x5d6b7a,
  rapid: 0xa9b2bb,
  current: 0xc000c0,
  tool: 0x111111,
  grid: 0xe2e4e0,
  gridCentre: 0xc9ccc6,
};
const CURRENT_WIDTH_PX = 4;
const TOOL_RADIUS_PX = 5;

export function webglAvailable() {
  try {
    const canvas = document.createElement('canvas');
    return Boolean(canvas.getContext('webgl2') || canvas.getContext('webgl'));
  } catch {
    return false;
  }
}

function pointOf(axes, row) {
  const at = (letter) => {
    const index = axes.indexOf(letter);
    return index < 0 ? 0 : row[index];
  };
  return [at('X'), at('Y'), at('Z')];
}

export class ToolpathView {
  constructor(container) {
    this.container = container;
    this.scene = new Scene();
    this.scene.background = new Color(COLOURS.background);
    this.camera = new OrthographicCamera(-1, 1, 1, -1, 0.1, 10000);
    this.camera.up.set(0, 0, 1);
    this.renderer = new WebGLRenderer({ antialias: true });
    this.renderer.setPixelRatio(window.devicePixelRatio || 1);
    container.append(this.renderer.domElement);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener('change', () => this.invalidate());
    this.halfSizeMm = 50;

    this.planned = new Group();
    this.scene.add(this.planned);
    this.currentLine = new LineSegments2(new LineSegmentsGeometry(),
      new LineMaterial({ color: COLOURS.current, linewidth: CURRENT_WIDTH_PX, depthTest: false }));
    this.currentLine.frustumCulled = false;
    this.currentLine.visible = false;
    // Under the executed path: the part of the line still to go stands out.
    this.currentLine.renderOrder = 1;
    this.scene.add(this.currentLine);
    this.tool = new Mesh(new SphereGeometry(1, 16, 12),
      new MeshBasicMaterial({ color: COLOURS.tool, depthTest: false }));
    this.tool.renderOrder = 4;
    this.tool.visible = false;
    this.scene.add(this.tool);
    this.origin = new AxesHelper(10);
    this.scene.add(this.origin);
    this.grid = null;

    this.trail = new Trail(this.scene, { renderOrder: 2 });

    this.segmentsByLine = new Map();
    this.points = [];
    this.shownLine = 0;
    this.frameRequested = false;
    new ResizeObserver(() => this.resize()).observe(container);
    this.resize();
    this.fit('iso');
  }

  // The planned path of GET /api/program's toolpath: feeds solid, rapids dashed. `refit`
  // frames it anew; a program planned again (a run's start, a new offset) keeps the view
  // the operator chose.
  setProgram(toolpath, { refit }) {
    for (const child of [...this.planned.children]) {
      child.geometry.dispose();
      this.planned.remove(child);
    }
    this.segmentsByLine.clear();
    this.points = [];
    if (!toolpath || !toolpath.points || toolpath.points.length < 2) {
      this.setLine(0, true);
      this.invalidate();
      return;
    }
    this.points = toolpath.points.map((row) => pointOf(toolpath.axes, row));
    const feeds = [];
    const rapids = [];
    for (let index = 0; index + 1 < this.points.length; index += 1) {
      const target = toolpath.rapid[index] ? rapids : feeds;
      target.push(...this.points[index], ...this.points[index + 1]);
      const line = toolpath.line[index];
      if (!this.segmentsByLine.has(line)) {
        this.segmentsByLine.set(line, []);
      }
      this.segmentsByLine.get(line).push(index);
    }
    const box = new Box3().setFromArray(this.points.flat());
    const size = box.getSize(new Vector3()).length() || 1;
    const feedLines = new LineSegments(
      new BufferGeometry().setAttribute('position', new Float32BufferAttribute(feeds, 3)),
      new LineBasicMaterial({ color: COLOURS.feed, depthTest: false }));
    const rapidLines = new LineSegments(
      new BufferGeometry().setAttribute('position', new Float32BufferAttribute(rapids, 3)),
      new LineDashedMaterial({ color: COLOURS.rapid, dashSize: size / 120, gapSize: size / 120,
        depthTest: false }));
    rapidLines.computeLineDistances();
    this.planned.add(rapidLines, feedLines);
    this.bounds = box;
    this.makeGrid(box);
    this.setLine(this.shownLine, true);
    if (refit) {
      this.fit();
    } else {
      this.invalidate();
    }
  }

  makeGrid(box) {
    if (this.grid) {
      this.grid.geometry.dispose();
      this.scene.remove(this.grid);
    }
    const centre = box.getCenter(new Vector3());
    const size = box.getSize(new Vector3());
    const extent = Math.max(size.x, size.y, 10);
    const spacing = 10 ** Math.floor(Math.log10(extent / 2));
    const cells = Math.ceil((extent * 1.2) / spacing / 2) * 2;
    this.grid = new GridHelper(cells * spacing, cells, COLOURS.gridCentre, COLOURS.grid);
    this.grid.rotation.x = Math.PI / 2;
    this.grid.position.set(Math.round(centre.x / spacing) * spacing,
      Math.round(centre.y / spacing) * spacing, box.min.z);
    this.grid.renderOrder = -1;
    this.scene.add(this.grid);
  }

  // The segments of program line `line` drawn over the rest (0: none).
  setLine(line, force = false) {
    if (line === this.shownLine && !force) {
      return;
    }
    this.shownLine = line;
    const segments = this.segmentsByLine.get(line) || [];
    const positions = new Float32Array(segments.length * 6);
    segments.forEach((segment, index) => {
      positions.set(this.points[segment], index * 6);
      positions.set(this.points[segment + 1], index * 6 + 3);
    });
    this.currentLine.geometry.dispose();
    this.currentLine.geometry = new LineSegmentsGeometry().setPositions(positions);
    this.currentLine.visible = segments.length > 0;
    this.invalidate();
  }

  setWorkOrigin(offsets) {
    this.origin.position.set(offsets.X || 0, offsets.Y || 0, offsets.Z || 0);
    this.invalidate();
  }

  // The tool where the machine measures it, and a trail point coloured by the size of the
  // push's peak following error (the vector over the axes).
  addPosition(state, { record }) {
    const axis = (name) => (state.axes[name] ? state.axes[name].machine_mm : 0);
    const point = [axis('X'), axis('Y'), axis('Z')];
    const [x, y, z] = point;
    const { position } = this.tool;
    if (!this.tool.visible || position.x !== x || position.y !== y || position.z !== z) {
      position.set(x, y, z);
      this.tool.visible = true;
      this.invalidate();
    }
    if (!record) {
      return;
    }
    let errorSquared = 0;
    for (const name of state.axis_order) {
      const peak = state.axes[name] ? state.axes[name].peak_error_mm : 0;
      errorSquared += peak * peak;
    }
    if (this.trail.add(point, Math.sqrt(errorSquared))) {
      this.invalidate();
    }
  }

  clearTrail() {
    this.trail.clear();
    this.invalidate();
  }

  setErrorScale(scaleMm) {
    this.trail.setScale(scaleMm);
    this.invalidate();
  }

  // The camera looking at the whole planned path (and the tool): from above, or from the
  // front right above; without a direction, the direction it has.
  fit(direction) {
    const box = this.bounds ? this.bounds.clone() : new Box3(
      new Vector3(-50, -50, -10), new Vector3(50, 50, 10));
    if (this.tool.visible) {
      box.expandByPoint(this.tool.position);
    }
    const centre = box.getCenter(new Vector3());
    const radius = Math.max(box.getSize(new Vector3()).length() / 2, 1);
    let view;
    if (direction === 'top') {
      view = new Vector3(0, -1e-4, 1);
    } else if (direction === 'iso') {
      view = new Vector3(1, -1.4, 1.2);
    } else {
      view = this.camera.position.clone().sub(this.controls.target);
      if (view.lengthSq() === 0) {
        view.set(1, -1.4, 1.2);
      }
    }
    view.normalize();
    const distance = radius * 10 + 100;
    this.camera.position.copy(centre).addScaledVector(view, distance);
    this.camera.near = 0.01;
    this.camera.far = distance * 2 + radius * 2;
    this.camera.zoom = 1;
    this.halfSizeMm = radius * 1.1;
    this.controls.target.copy(centre);
    this.updateFrustum();
    this.controls.update();
    this.invalidate();
  }

  updateFrustum() {
    const width = this.container.clientWidth || 1;
    const height = this.container.clientHeight || 1;
    const aspect = width / height;
    const half = this.halfSizeMm;
    const halfHeight = aspect >= 1 ? half : half / aspect;
    const halfWidth = halfHeight * aspect;
    Object.assign(this.camera, { left: -halfWidth, right: halfWidth, top: halfHeight, bottom: -halfHeight });
    this.camera.updateProjectionMatrix();
  }

  resize() {
    const width = this.container.clientWidth;
    const height = this.container.clientHeight;
    if (!width || !height) {
      return;
    }
    this.renderer.setSize(width, height);
    this.updateFrustum();
    this.invalidate();
  }

  // Drawn at the next animation frame, at most once a frame however many pushes came.
  invalidate() {
    if (this.frameRequested) {
      return;
    }
    this.frameRequested = true;
    requestAnimationFrame(() => {
      this.frameRequested = false;
      this.render();
    });
  }

  render() {
    const height = this.container.clientHeight || 1;
    const mmPerPixel = (this.camera.top - this.camera.bottom) / this.camera.zoom / height;
    this.tool.scale.setScalar(TOOL_RADIUS_PX * mmPerPixel);
    this.renderer.render(this.scene, this.camera);
  }
}
