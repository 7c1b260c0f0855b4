// rekon's live map: a WebSocket (/ws) brings the full state, then updates
// (services/viewer/include/rekon/viewer/protocol.hpp has the format). Blocks
// are binary messages, everything else JSON text. Counters for tests live on
// <body data-*>: blocks, vertices, triangles, updates (blocks replaced), messages.
'use strict';

const HIGHLIGHT_MS = 1500;  // a corrected block glows this long, so a person sees the correction land
const BLOCK_MAGIC = 0x31424B52;

const body = document.body;
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio || 1);
renderer.setClearColor(0x1e2328);
document.getElementById('view').appendChild(renderer.domElement);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(60, 1, 0.01, 200);
camera.up.set(0, -1, 0);  // camera frames: y points down in the images, so "up" is -y
camera.position.set(0, -1, -3);
const controls = new THREE.OrbitControls(camera, renderer.domElement);
let userMoved = false;
let dirty = true;  // drawn only when something changed: a large map costs nothing while it stands still
controls.addEventListener('start', () => { userMoved = true; });
controls.addEventListener('change', () => { dirty = true; });
scene.add(new THREE.AmbientLight(0xffffff, 0.55));
const sun = new THREE.DirectionalLight(0xffffff, 0.6);
sun.position.set(1, -2, -1.5);
scene.add(sun);

const meshMaterial = new THREE.MeshLambertMaterial({ vertexColors: THREE.VertexColors, side: THREE.DoubleSide });
const highlightMaterial = new THREE.MeshLambertMaterial({ vertexColors: THREE.VertexColors, side: THREE.DoubleSide,
  emissive: 0xff7a00, emissiveIntensity: 0.6 });
const blocks = new Map();  // "x y z" -> THREE.Mesh
const counts = { blocks: 0, vertices: 0, triangles: 0, updates: 0, messages: 0 };

// ---- blocks --------------------------------------------------------------

// A block message -> {key, vertices, triangles, positions, colors, indices}, or null when malformed.
function decodeBlock(buffer) {
  if (buffer.byteLength < 32) return null;
  const v = new DataView(buffer);
  if (v.getUint32(0, true) !== BLOCK_MAGIC) return null;
  const n = v.getUint32(24, true), t = v.getUint32(28, true);
  const colorsAt = 32 + 12 * n, indicesAt = colorsAt + ((3 * n + 3) & ~3);
  if (indicesAt + 12 * t !== buffer.byteLength) return null;
  return {
    key: v.getInt32(4, true) + ' ' + v.getInt32(8, true) + ' ' + v.getInt32(12, true),
    vertices: n, triangles: t,
    positions: new Float32Array(buffer, 32, 3 * n),
    colors: new Uint8Array(buffer, colorsAt, 3 * n),
    indices: new Uint32Array(buffer, indicesAt, 3 * t),
  };
}

function removeBlock(key) {
  const old = blocks.get(key);
  if (!old) return false;
  scene.remove(old);
  old.geometry.dispose();
  counts.blocks -= 1;
  counts.vertices -= old.userData.vertices;
  counts.triangles -= old.userData.triangles;
  blocks.delete(key);
  return true;
}

function applyBlock(buffer) {
  const b = decodeBlock(buffer);
  if (!b) return;
  const replaced = removeBlock(b.key);
  if (b.vertices === 0) return;
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(b.positions, 3));
  g.setAttribute('color', new THREE.BufferAttribute(b.colors, 3, true));
  g.setIndex(new THREE.BufferAttribute(b.indices, 1));
  g.computeVertexNormals();
  const m = new THREE.Mesh(g, replaced ? highlightMaterial : meshMaterial);
  m.userData = { vertices: b.vertices, triangles: b.triangles, until: replaced ? performance.now() + HIGHLIGHT_MS : 0 };
  scene.add(m);
  blocks.set(b.key, m);
  counts.blocks += 1;
  counts.vertices += b.vertices;
  counts.triangles += b.triangles;
  if (replaced) counts.updates += 1;
  needsFit = true;
}

function endHighlights(now) {
  for (const m of blocks.values()) {
    if (m.userData.until && now > m.userData.until) {
      m.material = meshMaterial;
      m.userData.until = 0;
      dirty = true;
    }
  }
}

// ---- camera, trajectory, keyframes, loop closures --------------------------

function poseMatrix(p) {  // [tx,ty,tz,qx,qy,qz,qw] -> Matrix4
  return new THREE.Matrix4().compose(new THREE.Vector3(p[0], p[1], p[2]),
    new THREE.Quaternion(p[3], p[4], p[5], p[6]), new THREE.Vector3(1, 1, 1));
}

function frustum(color, size) {  // a pinhole camera looking down +z, y down
  const w = 0.6 * size, h = 0.45 * size, d = size;
  const c = [[-w, -h, d], [w, -h, d], [w, h, d], [-w, h, d]];
  const pts = [];
  for (let i = 0; i < 4; i++) pts.push(0, 0, 0, ...c[i], ...c[i], ...c[(i + 1) % 4]);
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.Float32BufferAttribute(pts, 3));
  const lines = new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color }));
  lines.matrixAutoUpdate = false;
  return lines;
}

const cameraFrustum = frustum(0x4ab0ff, 0.25);
cameraFrustum.visible = false;
scene.add(cameraFrustum);
let trajectory = [];
const trajectoryLine = new THREE.Line(new THREE.BufferGeometry(), new THREE.LineBasicMaterial({ color: 0x4ab0ff }));
scene.add(trajectoryLine);
const keyframePoints = new THREE.Points(new THREE.BufferGeometry(), new THREE.PointsMaterial({ color: 0xffd24a, size: 0.04 }));
scene.add(keyframePoints);
const loopLines = new THREE.LineSegments(new THREE.BufferGeometry(), new THREE.LineBasicMaterial({ color: 0xff4a4a }));
scene.add(loopLines);
let keyframes = new Map();  // id -> [x, y, z]
let loopEdges = [];
let cameraPosition = null;

function setPositions(object, flat) {
  object.geometry.dispose();
  object.geometry = new THREE.BufferGeometry();
  object.geometry.setAttribute('position', new THREE.Float32BufferAttribute(flat, 3));
}

function drawLoops() {
  const flat = [];
  for (const [a, b] of loopEdges) {
    if (keyframes.has(a) && keyframes.has(b)) flat.push(...keyframes.get(a), ...keyframes.get(b));
  }
  setPositions(loopLines, flat);
}

const onText = {
  camera(m) {
    cameraFrustum.matrix.copy(poseMatrix(m.pose));
    cameraFrustum.visible = true;
    cameraPosition = new THREE.Vector3(m.pose[0], m.pose[1], m.pose[2]);
    if (!m.lost) {
      trajectory.push(m.pose[0], m.pose[1], m.pose[2]);
      setPositions(trajectoryLine, trajectory);
    }
  },
  trajectory(m) {
    trajectory = m.points.slice();
    setPositions(trajectoryLine, trajectory);
  },
  keyframes(m) {
    keyframes = new Map(m.keyframes.map((k) => [k.id, k.pose.slice(0, 3)]));
    setPositions(keyframePoints, [].concat(...keyframes.values()));
    drawLoops();
  },
  edges(m) {
    loopEdges = m.edges;
    drawLoops();
  },
  status(m) { drawStatus(m.services); },
};

// ---- status panel ------------------------------------------------------------

// The few stats worth a glance, when the service publishes them.
function notes(statsText) {
  let s;
  try { s = JSON.parse(statsText || '{}'); } catch (e) { return ''; }
  const keys = ['reintegrations', 'frames_dropped', 'dropped_frames', 'queued_frames', 'queue_depth', 'loop_closures', 'keyframes'];
  return keys.filter((k) => typeof s[k] === 'number').map((k) => k.replace(/_/g, ' ') + ' ' + s[k]).join(', ');
}

function cell(row, text, cls) {
  const td = row.insertCell();
  td.textContent = text;
  if (cls) td.className = cls;
}

function drawStatus(services) {
  const tbody = document.querySelector('#status tbody');
  tbody.textContent = '';
  for (const name of Object.keys(services).sort()) {
    const s = services[name];
    const row = tbody.insertRow();
    cell(row, name);
    cell(row, s.state);
    cell(row, s.last_frame >= 0 ? String(s.last_frame) : '');
    cell(row, s.frames_per_s ? s.frames_per_s.toFixed(1) : '');
    cell(row, notes(s.stats), 'notes');
  }
}

function drawCounts() {
  for (const k of Object.keys(counts)) body.dataset[k] = String(counts[k]);
  document.getElementById('counts').textContent =
    counts.blocks + ' blocks, ' + counts.vertices + ' vertices, ' + counts.triangles + ' triangles, ' +
    counts.updates + ' corrections, ' + keyframes.size + ' keyframes, ' + loopEdges.length + ' loop closures';
}

// ---- view ----------------------------------------------------------------------

let needsFit = false;
let lastFit = 0;

function fitView() {
  const box = new THREE.Box3();
  for (const m of blocks.values()) {
    if (!m.geometry.boundingBox) m.geometry.computeBoundingBox();
    box.union(m.geometry.boundingBox);
  }
  if (box.isEmpty()) return;
  const center = box.getCenter(new THREE.Vector3());
  const radius = Math.max(0.2, box.getSize(new THREE.Vector3()).length() / 2);
  controls.target.copy(center);
  camera.position.copy(center).add(new THREE.Vector3(0, -0.6, -1).normalize().multiplyScalar(radius * 1.9));
  camera.near = radius / 100;
  camera.far = radius * 20;
  camera.updateProjectionMatrix();
  controls.update();
  dirty = true;
}

document.getElementById('fit').addEventListener('click', () => { userMoved = false; fitView(); });

function follow() {
  if (!document.getElementById('follow').checked || !cameraPosition) return;
  const offset = camera.position.clone().sub(controls.target);
  if (controls.target.equals(cameraPosition)) return;
  controls.target.copy(cameraPosition);
  dirty = true;
  camera.position.copy(cameraPosition).add(offset);
}

function resize() {
  const w = window.innerWidth, h = window.innerHeight;
  renderer.setSize(w, h);
  camera.aspect = w / Math.max(1, h);
  camera.updateProjectionMatrix();
  dirty = true;
}
window.addEventListener('resize', resize);
resize();

function frame(now) {
  endHighlights(now);
  if (needsFit && !userMoved && now - lastFit > 500) {
    fitView();
    needsFit = false;
    lastFit = now;
  }
  follow();
  controls.update();
  if (dirty) renderer.render(scene, camera);
  dirty = false;
  requestAnimationFrame(frame);
}
requestAnimationFrame(frame);

// ---- connection -------------------------------------------------------------------

function connect() {
  const status = document.getElementById('connection');
  const ws = new WebSocket((location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/ws');
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => {
    for (const key of [...blocks.keys()]) removeBlock(key);  // the server sends every block again
    status.textContent = 'live';
    status.className = 'ok';
    body.dataset.connected = '1';
  };
  ws.onmessage = (e) => {
    counts.messages += 1;
    if (typeof e.data === 'string') {
      let m;
      try { m = JSON.parse(e.data); } catch (err) { return; }
      if (onText[m.type]) onText[m.type](m);
    } else {
      applyBlock(e.data);
    }
    dirty = true;
    drawCounts();
  };
  ws.onclose = () => {
    status.textContent = 'disconnected; retrying';
    status.className = 'lost';
    body.dataset.connected = '0';
    setTimeout(connect, 1000);  // the server sends the whole state again on connect
  };
}
connect();
