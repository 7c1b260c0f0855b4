// rekon's live map: a WebSocket (/ws) brings the full state, then updates
// (services/viewer/include/rekon/viewer/protocol.hpp has the format). Blocks
// are binary messages, everything else JSON text. Counters for tests live on
// <body data-*>: blocks, vertices, triangles, updates (blocks replaced),
// corrections and final_pass (block versions a graph update's re-integration
// or the final pass made: those are highlighted), coarse (blocks shown as a
// coarse mesh until their full one comes), messages, webgl (0: none), and the
// update latency (latency_samples, latency_ms_p50, latency_ms_p95: every block
// version; latency_full_*: full meshes only; latency_new_*: a block's first
// appearance), which the page also reports to the server once a second
// (/state.json's "clients").
'use strict';

const HIGHLIGHT_MS = 1500;  // a corrected block glows this long, so a person sees the correction land
const BLOCK_MAGIC = 0x32424B52;  // "RKB2"
const BLOCK_HEADER_BYTES = 36;
const CAUSE_CORRECTION = 1, CAUSE_FINAL_PASS = 2;  // rekon::BlockCause; 0 is new data
// Latencies are counted in 10 ms bins up to 2 minutes (longer ones in the
// last): a whole run's quantiles at a constant cost (they were the newest
// 20000 samples, which a 1000-frame run outgrew: its first half went uncounted).
const LATENCY_BIN_MS = 10, LATENCY_BINS = 12000;
// A mapper's block versions are wall-clock microseconds of the change; smaller
// ones (a test's 1, 2, 3) carry no time.
const MIN_TIME_VERSION = 1e15;
// A coarse mesh (half resolution, sent first for a block the page never had)
// has an odd time version, one below its change's full mesh (messages/mesh.lcm).
function isCoarse(version) { return version >= MIN_TIME_VERSION && version % 2 === 1; }

const body = document.body;
// The status and the counts need no WebGL: without it they still work, and one line says what is missing.
function makeRenderer() {
  try {
    const r = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    r.setPixelRatio(window.devicePixelRatio || 1);
    r.setClearColor(0x1e2328);
    document.getElementById('view').appendChild(r.domElement);
    body.dataset.webgl = '1';
    return r;
  } catch (e) {
    const note = document.getElementById('nowebgl');
    note.textContent = 'The 3D view needs WebGL, which this browser does not offer (enable hardware acceleration ' +
      'or WebGL in its settings); the status and the counts below work without it.';
    note.hidden = false;
    for (const control of document.querySelectorAll('.needs3d')) control.hidden = true;  // nothing to follow or fit
    body.dataset.webgl = '0';
    return null;
  }
}
const renderer = makeRenderer();
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(60, 1, 0.01, 200);
camera.up.set(0, -1, 0);  // camera frames: y points down in the images, so "up" is -y
camera.position.set(0, -1, -3);
const controls = new THREE.OrbitControls(camera, renderer ? renderer.domElement : document.getElementById('view'));
let userMoved = false;
let dirty = true;  // drawn only when something changed: a large map costs nothing while it stands still
// Changes from the server are drawn at most every MAP_REDRAW_MS, and never
// more than 1/MAP_DRAW_SHARE of the time: a browser without a GPU (software
// WebGL) takes ~80 ms to draw a 7000-block map, and drawing it for every
// message would take the CPU the reconstruction needs on the same machine.
// What the user does (orbit, pan, zoom) is drawn at once.
const MAP_REDRAW_MS = 250;
const MAP_DRAW_SHARE = 5;
let mapChanged = false;
let lastDrawn = 0, lastDrawMs = 0;
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
// position_sum: every vertex coordinate added up, as the server does (/state.json):
// equal sums mean the page holds the same versions of the blocks.
const counts = { blocks: 0, vertices: 0, triangles: 0, updates: 0, corrections: 0, final_pass: 0, coarse: 0,
  messages: 0, position_sum: 0 };

// Update latency: from a block's change in the mapper (its version) to the
// first frame drawn with it, for blocks that arrive after the state sent on
// connect (older ones were not changes). Same clock: the viewer on the mapper's host.
// Where the page's own time goes (ms, since it loaded): handling messages, and drawing.
const cost = { handle_ms: 0, draw_ms: 0 };
let live = false;
let connected = false;    // the WebSocket is open
let lastServices = {};    // the newest status message's services
// Change times (ms) of blocks applied since the last frame drawn, and the
// latencies once drawn: of every version, of full meshes, of first appearances.
const drawnPending = [];
function histogram() { return { bins: new Uint32Array(LATENCY_BINS), count: 0 }; }
const latencies = { all: histogram(), full: histogram(), new: histogram() };
function addLatency(h, ms) {
  h.bins[Math.min(LATENCY_BINS - 1, Math.max(0, Math.floor(ms / LATENCY_BIN_MS)))] += 1;
  h.count += 1;
}

// ---- blocks --------------------------------------------------------------

// A block message -> {key, vertices, triangles, positions, colors, indices}, or null when malformed.
function decodeBlock(buffer) {
  if (buffer.byteLength < BLOCK_HEADER_BYTES) return null;
  const v = new DataView(buffer);
  if (v.getUint32(0, true) !== BLOCK_MAGIC) return null;
  const n = v.getUint32(24, true), t = v.getUint32(28, true);
  const colorsAt = BLOCK_HEADER_BYTES + 12 * n, indicesAt = colorsAt + ((3 * n + 3) & ~3);
  if (indicesAt + 12 * t !== buffer.byteLength) return null;
  return {
    key: v.getInt32(4, true) + ' ' + v.getInt32(8, true) + ' ' + v.getInt32(12, true),
    version: v.getFloat64(16, true),
    cause: v.getUint8(32),
    vertices: n, triangles: t,
    positions: new Float32Array(buffer, BLOCK_HEADER_BYTES, 3 * n),
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
  counts.position_sum -= old.userData.position_sum;
  if (old.userData.coarse) counts.coarse -= 1;
  blocks.delete(key);
  return true;
}

function applyBlock(buffer) {
  const b = decodeBlock(buffer);
  if (!b) return;
  const old = blocks.get(b.key);
  const wasCoarse = old ? old.userData.coarse : false;
  const replaced = removeBlock(b.key);
  const coarse = isCoarse(b.version);
  if (live && b.version >= MIN_TIME_VERSION) drawnPending.push({ changed: b.version / 1000, full: !coarse, new: !replaced });
  // A coarse mesh's full one follows with the same cause: counted then.
  if (!coarse && b.cause === CAUSE_CORRECTION) counts.corrections += 1;
  if (!coarse && b.cause === CAUSE_FINAL_PASS) counts.final_pass += 1;
  if (b.vertices === 0) return;
  // Highlighted: what a correction changed, not a block that only grew with new data.
  const corrected = b.cause === CAUSE_CORRECTION || b.cause === CAUSE_FINAL_PASS;
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(b.positions, 3));
  g.setAttribute('color', new THREE.BufferAttribute(b.colors, 3, true));
  g.setIndex(new THREE.BufferAttribute(b.indices, 1));
  g.computeVertexNormals();
  const m = new THREE.Mesh(g, corrected ? highlightMaterial : meshMaterial);
  let sum = 0;
  for (const x of b.positions) sum += x;
  m.userData = { vertices: b.vertices, triangles: b.triangles, position_sum: sum, coarse,
    until: corrected ? performance.now() + HIGHLIGHT_MS : 0 };
  scene.add(m);
  blocks.set(b.key, m);
  counts.blocks += 1;
  counts.vertices += b.vertices;
  counts.triangles += b.triangles;
  counts.position_sum += sum;
  if (coarse) counts.coarse += 1;
  if (replaced && !wasCoarse) counts.updates += 1;  // a coarse mesh completed is no update
  needsFit = true;
}

function endHighlights(now) {
  for (const m of blocks.values()) {
    if (m.userData.until && now > m.userData.until) {
      m.material = meshMaterial;
      m.userData.until = 0;
      mapChanged = true;
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
  status(m) {
    lastServices = m.services;
    drawStatus(m.services);
  },
  live() { live = true; },
};

// ---- update latency ------------------------------------------------------------

function noteDrawn() {
  if (drawnPending.length === 0) return;
  const now = Date.now();
  for (const p of drawnPending) {
    addLatency(latencies.all, now - p.changed);
    if (p.full) addLatency(latencies.full, now - p.changed);
    if (p.new) addLatency(latencies.new, now - p.changed);
  }
  drawnPending.length = 0;
}

// The upper edge of the bin that holds the q-quantile (ms).
function latencyQuantile(h, q) {
  if (h.count === 0) return 0;
  const rank = Math.min(h.count - 1, Math.floor(q * h.count));
  let seen = 0;
  for (let i = 0; i < LATENCY_BINS; i++) {
    seen += h.bins[i];
    if (seen > rank) return (i + 1) * LATENCY_BIN_MS;
  }
  return LATENCY_BINS * LATENCY_BIN_MS;
}

// The page's counts and latency, for the DOM (tests) and the server (/state.json).
function report() {
  const r = Object.assign({ type: 'report' }, counts, {
    handle_ms: Math.round(cost.handle_ms), draw_ms: Math.round(cost.draw_ms) });
  for (const [name, prefix] of [['all', 'latency'], ['full', 'latency_full'], ['new', 'latency_new']]) {
    const h = latencies[name];
    r[prefix + '_samples'] = h.count;
    r[prefix + '_ms_p50'] = latencyQuantile(h, 0.5);
    r[prefix + '_ms_p95'] = latencyQuantile(h, 0.95);
  }
  return r;
}

// ---- status panel ------------------------------------------------------------

// The few stats worth a glance, when the service publishes them.
function notes(statsText) {
  let s;
  try { s = JSON.parse(statsText || '{}'); } catch (e) { return ''; }
  const keys = ['queued_frames', 'frames_dropped', 'frames_dropped_when_full', 'lost_frames', 'reintegrations',
    'kf_keyframes', 'keyframes', 'loop_closures', 'loop_closures_accepted', 'clients', 'outages',
    'frames_missed_in_outages'];
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
    // A restarted service says so: it was killed or crashed, and came back.
    cell(row, s.restarts > 0 ? s.state + ' (' + s.restarts + (s.restarts > 1 ? ' restarts)' : ' restart)') : s.state);
    cell(row, s.last_frame >= 0 ? String(s.last_frame) : '');
    cell(row, s.frames_per_s && s.state !== 'exited' ? s.frames_per_s.toFixed(1) : '');  // an exited service has no rate
    cell(row, notes(s.stats), 'notes');
  }
  drawConnection();
}

// The header: "live" while the run goes on; once every service but the
// viewer has exited, the page shows a finished run's final map.
function runFinished() {
  const names = Object.keys(lastServices).filter((n) => n !== 'viewer');
  return names.length > 0 && names.every((n) => lastServices[n].state === 'exited');
}

function drawConnection() {
  const status = document.getElementById('connection');
  if (!connected) {
    status.textContent = 'disconnected; retrying';
    status.className = 'lost';
  } else if (runFinished()) {
    status.textContent = 'run finished: its final map';
    status.className = 'done';
  } else {
    status.textContent = 'live';
    status.className = 'ok';
  }
  body.dataset.runFinished = runFinished() ? '1' : '0';
}

function drawCounts() {
  for (const k of Object.keys(counts)) body.dataset[k] = String(counts[k]);
  document.getElementById('counts').textContent =
    counts.blocks + ' blocks, ' + counts.vertices + ' vertices, ' + counts.triangles + ' triangles, ' +
    counts.corrections + ' blocks corrected' + (counts.final_pass ? ', ' + counts.final_pass + ' by the final pass' : '') +
    ', ' + keyframes.size + ' keyframes, ' + loopEdges.length + ' loop closures';
}

function drawLatency(r) {
  body.dataset.latencySamples = String(r.latency_samples);
  body.dataset.latencyMsP50 = String(r.latency_ms_p50);
  body.dataset.latencyMsP95 = String(r.latency_ms_p95);
  document.getElementById('latency').textContent = r.latency_samples
    ? 'update latency ' + r.latency_ms_p50 + ' ms (p50), ' + r.latency_ms_p95 + ' ms (p95)' +
      (r.latency_full_samples ? '; full mesh ' + r.latency_full_ms_p50 + ' / ' + r.latency_full_ms_p95 + ' ms' : '') : '';
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
  if (renderer) renderer.setSize(w, h);
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
  if (mapChanged && now - lastDrawn >= Math.max(MAP_REDRAW_MS, MAP_DRAW_SHARE * lastDrawMs)) {
    dirty = true;
    mapChanged = false;
  }
  if (dirty && renderer) {
    const t0 = performance.now();
    renderer.render(scene, camera);
    renderer.getContext().finish();  // the drawing's cost lands here, not in the next message
    lastDrawMs = performance.now() - t0;
    cost.draw_ms += lastDrawMs;
    lastDrawn = now;
    noteDrawn();
  }
  dirty = false;
  requestAnimationFrame(frame);
}
requestAnimationFrame(frame);

// ---- connection -------------------------------------------------------------------

function connect() {
  const ws = new WebSocket((location.protocol === 'https:' ? 'wss://' : 'ws://') + location.host + '/ws');
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => {
    live = false;
    for (const key of [...blocks.keys()]) removeBlock(key);  // the server sends every block again
    connected = true;
    drawConnection();
    body.dataset.connected = '1';
  };
  ws.onmessage = (e) => {
    const t0 = performance.now();
    counts.messages += 1;
    if (typeof e.data === 'string') {
      let m;
      try { m = JSON.parse(e.data); } catch (err) { return; }
      if (onText[m.type]) onText[m.type](m);
    } else {
      applyBlock(e.data);
    }
    mapChanged = true;
    drawCounts();
    cost.handle_ms += performance.now() - t0;
  };
  ws.onclose = () => {
    connected = false;
    drawConnection();
    body.dataset.connected = '0';
    setTimeout(() => { socket = connect(); }, 1000);  // the server sends the whole state again on connect
  };
  return ws;
}

let socket = connect();
setInterval(() => {
  const r = report();
  drawLatency(r);
  if (socket.readyState === WebSocket.OPEN) socket.send(JSON.stringify(r));
}, 1000);
