// splat4d view: the page. The server renders; this script keeps the camera and the time,
// asks for frames over one WebSocket and draws them on the canvas.
'use strict';

const $ = (id) => document.getElementById(id);
// The run's secret, from the address the command printed: the server answers only requests
// that carry it.
const TOKEN = encodeURIComponent(new URLSearchParams(location.search).get('token') || '');
window.splat4dFrames = 0;

// Camera: eye and an orthonormal OpenGL basis (x right, y up, z backward), orbiting `centre`.
const cam = { eye: [0, 0, 5], right: [1, 0, 0], up: [0, 1, 0], back: [0, 0, 1], fov: 40,
  centre: [0, 0, 0], worldUp: [0, 1, 0] };
const st = { t0: 0, t1: 0, time: 0, playing: false, loop: true, speed: 1, lastMove: -1e9, lastScrub: -1e9,
  sentId: 0, gotId: 0, drawnId: 0, lastLow: false, dirty: true, views: [], live: false,
  version: 0, keyframes: [], path: null, pathAction: null, playback: null, kernels: 0,
  maxSide: 4096, drawTimes: [], playScale: 1 };
const MOVE_REST_MS = 250;     // the camera is resting this long after the last move
const LOW_SCALE = 0.5;        // resolution while it moves
const PLAY_BUDGET_MS = 25;    // while time plays, the resolution adapts to keep frames this cheap
const SWEEP_SECONDS = 5;      // the whole time range plays in this long at 1×

const add = (a, b) => a.map((v, i) => v + b[i]);
const sub = (a, b) => a.map((v, i) => v - b[i]);
const scale = (a, s) => a.map((v) => v * s);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => scale(a, 1 / (Math.hypot(a[0], a[1], a[2]) || 1));
// Rodrigues: v turned by `angle` about the unit `axis`.
function rotate(v, axis, angle) {
  const c = Math.cos(angle), s = Math.sin(angle);
  return add(add(scale(v, c), scale(cross(axis, v), s)), scale(axis, dot(axis, v) * (1 - c)));
}

function c2w() {
  const { right: r, up: u, back: b, eye: e } = cam;
  return [r[0], u[0], b[0], e[0], r[1], u[1], b[1], e[1], r[2], u[2], b[2], e[2], 0, 0, 0, 1];
}
function setPose(m, fov) {
  cam.right = norm([m[0], m[4], m[8]]);
  cam.up = norm([m[1], m[5], m[9]]);
  cam.back = norm([m[2], m[6], m[10]]);
  cam.eye = [m[3], m[7], m[11]];
  if (fov) cam.fov = fov;
  st.dirty = true;
}

function moved() { st.lastMove = performance.now(); st.dirty = true; st.playback = null; }
function orbit(dx, dy) {
  const yaw = -dx * 0.006, pitch = -dy * 0.006;
  const turn = (axis, angle) => {
    cam.eye = add(cam.centre, rotate(sub(cam.eye, cam.centre), axis, angle));
    for (const k of ['right', 'up', 'back']) cam[k] = norm(rotate(cam[k], axis, angle));
  };
  turn(cam.worldUp, yaw);
  const before = { eye: cam.eye, right: cam.right, up: cam.up, back: cam.back };
  turn(cam.right, pitch);
  if (Math.abs(dot(cam.back, cam.worldUp)) > 0.995) Object.assign(cam, before);
  moved();
}
function pan(dx, dy) {
  const canvas = $('view');
  const dist = Math.hypot(...sub(cam.eye, cam.centre));
  const perPixel = 2 * dist * Math.tan(cam.fov * Math.PI / 360) / Math.max(1, canvas.clientHeight);
  const shift = add(scale(cam.right, -dx * perPixel), scale(cam.up, dy * perPixel));
  cam.eye = add(cam.eye, shift);
  cam.centre = add(cam.centre, shift);
  moved();
}
function zoom(amount) {
  const offset = sub(cam.eye, cam.centre);
  const factor = Math.exp(amount);
  if (Math.hypot(...offset) * factor < 1e-4) return;
  cam.eye = add(cam.centre, scale(offset, factor));
  moved();
}

function setTime(t, fromSlider) {
  st.time = Math.min(st.t1, Math.max(st.t0, t));
  if (!fromSlider) $('time').value = st.time;
  $('tau').textContent = st.time.toFixed(3);
  st.dirty = true;
}
function setPlaying(on) {
  st.playing = on && st.t1 > st.t0;
  $('play').textContent = st.playing ? 'pause' : 'play';
}

// --- the socket ----------------------------------------------------------------------------
let ws = null;
function connect() {
  ws = new WebSocket(`ws://${location.host}/ws?token=${TOKEN}`);
  ws.binaryType = 'arraybuffer';
  ws.onmessage = (ev) => (typeof ev.data === 'string' ? onText(JSON.parse(ev.data)) : onBinary(ev.data));
  ws.onclose = () => { $('status').textContent = 'disconnected'; };
}
function send(message) { if (ws && ws.readyState === 1) ws.send(JSON.stringify(message)); }

function onText(m) {
  if (m.type === 'hello') return onHello(m);
  if (m.type === 'error') {
    if (m.id) st.gotId = Math.max(st.gotId, m.id);
    $('status').textContent = m.message;
    return;
  }
  if (m.type === 'path') return onPath(m);
  if (m.type === 'live') return onLive(m);
}

function onHello(m) {
  document.title = `splat4d view: ${m.title}`;
  $('title').textContent = m.title;
  [st.t0, st.t1] = m.scene.time_range;
  // The slider reaches every dataset view's time.
  for (const v of m.views) { st.t0 = Math.min(st.t0, v.time); st.t1 = Math.max(st.t1, v.time); }
  st.kernels = m.scene.kernels;
  st.maxSide = m.max_side;
  $('kernels').textContent = m.scene.kernels;
  cam.centre = m.scene.centre;
  cam.worldUp = m.scene.up;
  if (m.camera) setPose(m.camera.c2w, m.camera.fov);
  const slider = $('time');
  slider.min = st.t0; slider.max = st.t1;
  slider.step = st.t1 > st.t0 ? (st.t1 - st.t0) / 1000 : 1;
  slider.disabled = !(st.t1 > st.t0);
  setTime(st.t0);
  st.live = m.live;
  st.views = m.views;
  st.ready = true;
  if (m.views.length) {
    $('views-section').hidden = false;
    for (const v of m.views) {
      const o = document.createElement('option');
      o.value = v.index;
      o.textContent = `${v.name} · t ${v.time.toFixed(3)}`;
      $('views').appendChild(o);
    }
  }
  $('live-section').hidden = !m.live;
  // A dynamic scene plays on arrival; a fit's viewer leaves the cores to the fit.
  setPlaying(!m.live);
}

function onBinary(buffer) {
  const n = new DataView(buffer).getUint32(0, true);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, n)));
  let at = 4 + n;
  const parts = {};
  for (const p of header.parts) {
    parts[p.name] = new Blob([new Uint8Array(buffer, at, p.bytes)], { type: p.mime });
    at += p.bytes;
  }
  if (header.type === 'frame') {
    st.gotId = Math.max(st.gotId, header.id);
    createImageBitmap(parts.frame).then((bitmap) => { draw(header, bitmap); tick(); });
  } else if (header.type === 'compare') {
    for (const name of ['render', 'truth', 'error']) {
      const img = $(`cmp-${name}`);
      if (img.src) URL.revokeObjectURL(img.src);
      img.src = URL.createObjectURL(parts[name]);
    }
    // An exact match has an infinite PSNR, which JSON carries as null.
    const psnr = header.psnr === null ? '∞' : header.psnr.toFixed(2);
    $('psnr').textContent = `${st.views[header.view].name}: PSNR ${psnr} dB`;
    $('compare').hidden = false;
  }
}

function draw(header, bitmap) {
  if (header.id < st.drawnId) { bitmap.close(); return; }
  st.drawnId = header.id;
  const first = $('first');
  if (first) first.remove();
  const canvas = $('view');
  const ctx = canvas.getContext('2d');
  ctx.imageSmoothingEnabled = true;
  ctx.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
  bitmap.close();
  window.splat4dFrames += 1;
  window.splat4dLast = header;
  // While time plays, the resolution follows the server's cost per frame.
  if (animating(performance.now()) && $('adaptive').checked) {
    const cost = header.render_ms + header.encode_ms;
    const full = canvas.width * canvas.height;
    const share = (header.width * header.height) / full;
    if (share >= st.playScale * st.playScale * 0.8) {
      if (cost > PLAY_BUDGET_MS) st.playScale = Math.max(LOW_SCALE, st.playScale * 0.9);
      else if (cost < 0.6 * PLAY_BUDGET_MS) st.playScale = Math.min(1, st.playScale * 1.05);
    }
  }
  const now = performance.now();
  st.drawTimes.push(now);
  while (st.drawTimes.length && st.drawTimes[0] < now - 1000) st.drawTimes.shift();
  $('fps').textContent = st.drawTimes.length;
  $('alive').textContent = header.alive;
  $('kernels').textContent = header.kernels;
  const ms = (v) => v.toFixed(1);
  $('server-ms').textContent = ms(header.render_ms + header.encode_ms + header.send_ms);
  $('render-ms').textContent = ms(header.render_ms);
  $('encode-ms').textContent = ms(header.encode_ms);
  $('send-ms').textContent = ms(header.send_ms);
  $('size').textContent = `${header.width}×${header.height}`;
}

// --- the frame loop ------------------------------------------------------------------------
function fullSize() {
  const canvas = $('view');
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.min(st.maxSide, Math.round(canvas.clientWidth * dpr)));
  const h = Math.max(1, Math.min(st.maxSide, Math.round(canvas.clientHeight * dpr)));
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w; canvas.height = h; st.dirty = true;
  }
  return [w, h];
}

// Time moves: playing, a path playing back, or the slider being dragged.
function animating(now) {
  return st.playing || !!st.playback || now - st.lastScrub < MOVE_REST_MS;
}

function requestFrame(now) {
  // Nothing is asked before the scene is known (a request sent into a closed socket would
  // count as in flight for ever).
  if (!st.ready || !ws || ws.readyState !== 1) return;
  const [w, h] = fullSize();
  const moving = now - st.lastMove < MOVE_REST_MS;
  const playing = animating(now) && $('adaptive').checked;
  const low = moving || (playing && st.playScale < 1);
  // At rest after moving: the full resolution once more.
  if (!low && st.lastLow) st.dirty = true;
  if (!st.dirty || st.sentId - st.gotId >= 2) return;
  const s = moving ? Math.min(LOW_SCALE, st.playScale) : playing ? st.playScale : 1;
  st.sentId += 1;
  send({ type: 'frame', id: st.sentId, c2w: c2w(), fov: cam.fov, width: Math.max(1, Math.round(w * s)),
    height: Math.max(1, Math.round(h * s)), time: st.time, lossless: $('lossless').checked });
  st.lastLow = low;
  st.dirty = false;
}

let lastTick = performance.now();
function tick() {
  const now = performance.now();
  const dt = Math.max(0, Math.min(0.1, (now - lastTick) / 1000));
  lastTick = now;
  if (st.playback) stepPlayback(now);
  else if (st.playing) {
    let t = st.time + dt * st.speed * (st.t1 - st.t0) / SWEEP_SECONDS;
    if (t > st.t1) {
      if (st.loop) t = st.t0 + (t - st.t1);
      else { t = st.t1; setPlaying(false); }
    }
    setTime(t);
  }
  requestFrame(now);
}
// Animation frames drive the page; a timer too, where they are throttled (hidden tabs,
// screenshot tools).
function animate() { tick(); requestAnimationFrame(animate); }

// --- dataset views -------------------------------------------------------------------------
function chooseView(index) {
  const v = st.views[index];
  if (!v) return;
  setPlaying(false);
  st.playback = null;
  setPose(v.c2w, v.fov);
  setTime(v.time);
  send({ type: 'compare', id: 0, view: v.index });
}

// --- camera paths: the server interpolates (the same code as `splat4d video --path`) -----------
function keyCount() {
  const n = st.keyframes.length;
  $('key-count').textContent = `${n} keyframe${n === 1 ? '' : 's'}`;
}
function askPath(action) {
  if (!st.keyframes.length) { $('status').textContent = 'add a keyframe first'; return; }
  st.pathAction = action;
  const [w, h] = fullSize();
  send({ type: 'path', keyframes: st.keyframes, fps: Number($('path-fps').value),
    seconds: Number($('path-seconds').value), width: w, height: h });
}
function onPath(m) {
  st.path = m;
  if (st.pathAction === 'save') {
    const blob = new Blob([JSON.stringify(m.file, null, 2)], { type: 'application/json' });
    const a = document.createElement('a');
    a.href = URL.createObjectURL(blob);
    a.download = 'camera_path.json';
    document.body.appendChild(a);
    a.click();
    a.remove();
  } else {
    setPlaying(false);
    st.playback = { start: performance.now(), fps: m.file.fps, frames: m.frames };
  }
  st.pathAction = null;
}
function stepPlayback(now) {
  const p = st.playback;
  const k = Math.floor((now - p.start) / 1000 * p.fps);
  if (k >= p.frames.length) { st.playback = null; return; }
  const f = p.frames[k];
  setPose(f.c2w, f.fov);
  setTime(f.time);
}

// --- a running fit ---------------------------------------------------------------------------
const history = [];
function onLive(m) {
  history.push(...m.points);
  if (m.version !== st.version) { st.version = m.version; st.dirty = true; }
  const last = history[history.length - 1];
  const psnr = [...history].reverse().find((p) => p.heldout_psnr !== null);
  $('live-text').textContent = last
    ? `step ${last.step} / ${m.steps}${m.done ? ' (done)' : ''} · ${last.kernels} kernels · loss ${last.loss.toExponential(3)}`
      + (psnr ? ` · held-out ${psnr.heldout_psnr.toFixed(2)} dB` : '')
    : 'waiting for the first step…';
  chart(last ? last.step : 1);
}
// The loss (log) and held-out PSNR over the steps so far, each scaled to its own range.
function chart(steps) {
  const canvas = $('chart');
  const ctx = canvas.getContext('2d');
  const { width: w, height: h } = canvas;
  ctx.clearRect(0, 0, w, h);
  const line = (values, colour) => {
    const pts = values.filter((p) => Number.isFinite(p[1]));
    if (!pts.length) return;
    let lo = Math.min(...pts.map((p) => p[1])), hi = Math.max(...pts.map((p) => p[1]));
    if (hi - lo < 1e-12) { lo -= 1; hi += 1; }
    ctx.strokeStyle = colour;
    ctx.beginPath();
    pts.forEach(([x, y], i) => {
      const px = x / Math.max(1, steps) * (w - 4) + 2, py = h - 4 - (y - lo) / (hi - lo) * (h - 8);
      if (i) ctx.lineTo(px, py); else ctx.moveTo(px, py);
    });
    ctx.stroke();
  };
  line(history.map((p) => [p.step, Math.log10(p.loss)]), '#f90');
  line(history.filter((p) => p.heldout_psnr !== null).map((p) => [p.step, p.heldout_psnr]), '#4cf');
  ctx.fillStyle = '#f90'; ctx.fillText('log10 loss', 6, 12);
  ctx.fillStyle = '#4cf'; ctx.fillText('held-out PSNR', 6, 24);
}

// --- input ---------------------------------------------------------------------------------
function listen() {
  const canvas = $('view');
  let drag = null;
  // Drags start anywhere but on a control (the panels' text does not block the view).
  const control = (t) => t instanceof Element && !!t.closest('button, input, select, label, a, #side');
  document.addEventListener('contextmenu', (e) => { if (!control(e.target)) e.preventDefault(); });
  document.addEventListener('pointerdown', (e) => {
    if (control(e.target)) return;
    e.preventDefault();
    try { canvas.setPointerCapture(e.pointerId); } catch (_) { /* a synthetic pointer */ }
    canvas.focus();
    drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.button === 1 || e.shiftKey };
  });
  document.addEventListener('pointermove', (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan || e.shiftKey) pan(dx, dy); else orbit(dx, dy);
  });
  const end = () => { drag = null; };
  document.addEventListener('pointerup', end);
  document.addEventListener('pointercancel', end);
  document.addEventListener('wheel', (e) => {
    if (control(e.target)) return;
    e.preventDefault();
    zoom(e.deltaY * 0.0015);
  }, { passive: false });
  window.addEventListener('keydown', (e) => {
    if (e.target instanceof HTMLInputElement && e.target.type !== 'range') return;
    if (e.target instanceof HTMLSelectElement) return;
    const step = 20;
    const keys = {
      ArrowLeft: () => (e.shiftKey ? pan(-step, 0) : orbit(-step, 0)),
      ArrowRight: () => (e.shiftKey ? pan(step, 0) : orbit(step, 0)),
      ArrowUp: () => (e.shiftKey ? pan(0, -step) : orbit(0, -step)),
      ArrowDown: () => (e.shiftKey ? pan(0, step) : orbit(0, step)),
      '+': () => zoom(-0.1), '=': () => zoom(-0.1), '-': () => zoom(0.1),
      ' ': () => setPlaying(!st.playing),
      k: () => $('key-add').click(),
    };
    if (keys[e.key]) { e.preventDefault(); keys[e.key](); }
  });
  const scrub = (e) => {
    setPlaying(false);
    st.playback = null;
    st.lastScrub = performance.now();
    setTime(Number(e.target.value), true);
  };
  $('time').addEventListener('input', scrub);
  $('time').addEventListener('change', scrub);
  $('play').addEventListener('click', () => setPlaying(!st.playing));
  $('loop').addEventListener('change', (e) => { st.loop = e.target.checked; });
  $('speed').addEventListener('change', (e) => { st.speed = Number(e.target.value); });
  $('lossless').addEventListener('change', () => { st.dirty = true; });
  $('views').addEventListener('change', (e) => { if (e.target.value !== '') chooseView(Number(e.target.value)); });
  $('key-add').addEventListener('click', () => {
    st.keyframes.push({ c2w: c2w(), fov: cam.fov, time: st.time });
    keyCount();
  });
  $('key-clear').addEventListener('click', () => { st.keyframes = []; keyCount(); });
  $('path-play').addEventListener('click', () => askPath('play'));
  $('path-save').addEventListener('click', () => askPath('save'));
  window.addEventListener('resize', () => { st.dirty = true; });
}

// For tests and scripts: the camera and time of the newest request, and controls.
window.splat4dState = () => ({
  moving: performance.now() - st.lastMove < MOVE_REST_MS || animating(performance.now()),
  sent: st.sentId, drawn: st.drawnId, dirty: st.dirty, views: st.views, path: st.path,
  keyframes: st.keyframes,
});
window.splat4d = {
  camera: () => ({ c2w: c2w(), fov: cam.fov, time: st.time, width: $('view').width, height: $('view').height }),
  setPlaying, setTime, chooseView, orbit,
};

// The first frame comes as an image the page's load waits for (so a screenshot taken at
// load shows the scene); frames over the socket replace it.
function firstFrame() {
  const canvas = $('view');
  const [w, h] = [Math.max(1, canvas.clientWidth), Math.max(1, canvas.clientHeight)];
  const img = new Image();
  img.id = 'first';
  img.alt = '';
  img.onload = () => {
    if (st.drawnId > 0) return;
    canvas.width = w; canvas.height = h;
    canvas.getContext('2d').drawImage(img, 0, 0, w, h);
    window.splat4dFrames += 1;
  };
  img.src = `/first.jpg?width=${w}&height=${h}&token=${TOKEN}`;
  // Shown over the canvas until the socket's first frame (an image is on screen as soon as
  // it loads; a canvas may be presented a frame later).
  canvas.after(img);
}

listen();
firstFrame();
connect();
requestAnimationFrame(animate);
setInterval(() => { if (performance.now() - lastTick > 30) tick(); }, 15);
