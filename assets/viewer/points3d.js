// A 3D view of coloured point clouds (binary PLY from the API), boxes and a camera path,
// with orbit and zoom. three.js is vendored.
import * as THREE from 'three';
import { OrbitControls } from './OrbitControls.js';

// Our exports' layout: x y z float, red green blue uchar, little-endian.
export function parsePly(buf) {
  const bytes = new Uint8Array(buf);
  const endTag = 'end_header\n';
  let text = '';
  let end = -1;
  for (let i = 0; i < Math.min(bytes.length, 4096); i++) {
    text += String.fromCharCode(bytes[i]);
    if (text.endsWith(endTag)) { end = i + 1; break; }
  }
  if (end < 0 || !text.includes('format binary_little_endian')) throw new Error('not a binary PLY');
  const n = parseInt((text.match(/element vertex (\d+)/) || [])[1] || '0', 10);
  const dv = new DataView(buf, end);
  const pos = new Float32Array(n * 3);
  const col = new Float32Array(n * 3);
  for (let i = 0; i < n; i++) {
    const o = i * 15;
    pos[3 * i] = dv.getFloat32(o, true);
    pos[3 * i + 1] = dv.getFloat32(o + 4, true);
    pos[3 * i + 2] = dv.getFloat32(o + 8, true);
    col[3 * i] = dv.getUint8(o + 12) / 255;
    col[3 * i + 1] = dv.getUint8(o + 13) / 255;
    col[3 * i + 2] = dv.getUint8(o + 14) / 255;
  }
  return { count: n, pos, col };
}

// clouds: [{ply: ArrayBuffer, size, color?}], boxes: [{min, max, color}],
// path: [[x,y,z], ...]. Returns the number of points drawn.
export function show(canvas, { clouds = [], boxes = [], path = [] }) {
  const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(1);
  renderer.setSize(canvas.clientWidth, canvas.clientHeight, false);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0x1b2230);
  const bounds = new THREE.Box3();
  let drawn = 0;
  for (const c of clouds) {
    const p = parsePly(c.ply);
    if (!p.count) continue;
    const geo = new THREE.BufferGeometry();
    geo.setAttribute('position', new THREE.BufferAttribute(p.pos, 3));
    geo.setAttribute('color', new THREE.BufferAttribute(p.col, 3));
    const mat = c.color
      ? new THREE.PointsMaterial({ size: c.size || 0.03, color: c.color })
      : new THREE.PointsMaterial({ size: c.size || 0.03, vertexColors: true });
    scene.add(new THREE.Points(geo, mat));
    geo.computeBoundingBox();
    bounds.union(geo.boundingBox);
    drawn += p.count;
  }
  for (const b of boxes) {
    const box = new THREE.Box3(new THREE.Vector3(...b.min), new THREE.Vector3(...b.max));
    scene.add(new THREE.Box3Helper(box, new THREE.Color(b.color || 0x30d158)));
    bounds.union(box);
  }
  if (path.length > 1) {
    const geo = new THREE.BufferGeometry().setFromPoints(path.map((p) => new THREE.Vector3(...p)));
    scene.add(new THREE.Line(geo, new THREE.LineBasicMaterial({ color: 0xff9f0a })));
    const dots = new THREE.Points(geo, new THREE.PointsMaterial({ size: 0.08, color: 0xff9f0a }));
    scene.add(dots);
    for (const p of path) bounds.expandByPoint(new THREE.Vector3(...p));
  }
  if (bounds.isEmpty()) bounds.set(new THREE.Vector3(-1, -1, -1), new THREE.Vector3(1, 1, 1));
  const center = bounds.getCenter(new THREE.Vector3());
  const size = bounds.getSize(new THREE.Vector3()).length();
  const camera = new THREE.PerspectiveCamera(50, canvas.clientWidth / canvas.clientHeight, size / 500, size * 10);
  camera.up.set(0, 0, 1);
  camera.position.set(center.x - 0.55 * size, center.y - 0.75 * size, center.z + 0.6 * size);
  const controls = new OrbitControls(camera, canvas);
  controls.target.copy(center);
  controls.update();
  const render = () => renderer.render(scene, camera);
  controls.addEventListener('change', render);
  render();
  return drawn;
}
