// track-web: the page. Frames arrive as binary messages (clients/frames.py gives the
// layout), are answered with "ack" at once, and only the newest one is drawn, on the next
// animation frame.
import { enuToGeodetic, formatLatLon } from './geo.js';
import { drawFrame, Raster, STATUS_NAMES, Trails, View } from './render.js';
import { showDetails } from './details.js';
import { Basemap } from './basemap.js';
import { Tiles } from './tiles.js';

const TRAIL_POINTS = 16;
const FIT_PERIOD = 2000; // ms: how often the view follows the tracks (key F)
const $ = (id) => document.getElementById(id);
const canvas = $('map');
// with alpha: an operator's tiles (--tiles) show through the background it leaves clear
const ctx = canvas.getContext('2d');
let tiles = null;
const view = new View();
const raster = new Raster();
const trails = new Trails(TRAIL_POINTS);
// the basemap unless the address says ?basemap=off (key G toggles it)
const basemap = new Basemap((name) => `/static/basemap/countries-${name}.json`,
                            () => { state.moved = true; });
const state = {
  config: { ns: '', origin: null, trail: 30 },
  frame: null, fresh: false, ids: [], idsSeq: -1,
  overlay: { sensors: [], interceptors: [], selectedRow: -1 },
  basemap: new URLSearchParams(location.search).get('basemap') !== 'off',
  selected: null, follow: true, fitted: -Infinity, fitFrame: null, moved: true, labels: 'auto', trails: true,
  drawn: [], drawMs: 0, received: 0, dropped: 0,
};

// ---------------------------------------------------------------- the stream
function parseFrame(buf) {
  const dv = new DataView(buf);
  if (dv.getUint32(0, true) !== 0x31465754) return null; // "TWF1"
  const n = dv.getUint32(4, true), t = dv.getFloat64(8, true);
  const idsSeq = dv.getUint32(16, true), idsLen = dv.getUint32(20, true);
  const extraLen = dv.getUint32(24, true), dropped = dv.getUint32(28, true);
  let off = 32;
  if (idsLen) {
    const text = new TextDecoder().decode(new Uint8Array(buf, off, idsLen)).replace(/\0+$/, '');
    state.ids = n ? text.split('\n') : [];
    state.idsSeq = idsSeq;
    trails.remap(state.ids);
  }
  off += idsLen;
  const extra = extraLen ? JSON.parse(new TextDecoder().decode(new Uint8Array(buf, off, extraLen))) : {};
  off += extraLen;
  if (idsSeq !== state.idsSeq) return null; // rows of an id list this page does not hold
  const pos = new Float32Array(buf, off, 3 * n); off += 12 * n;
  const vel = new Float32Array(buf, off, 3 * n); off += 12 * n;
  const sigma = new Float32Array(buf, off, n); off += 4 * n;
  const status = new Uint8Array(buf, off, n);
  let index = null;
  const ids = state.ids;
  const rowOf = (id) => {
    if (!index) { index = new Map(); ids.forEach((v, i) => index.set(v, i)); }
    const r = index.get(id);
    return r === undefined ? -1 : r;
  };
  return { n, t, ids, pos, vel, sigma, status, dropped, rowOf,
           interceptors: extra.interceptors || [] };
}

function connect() {
  const ws = new WebSocket(`${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/ws`);
  ws.binaryType = 'arraybuffer';
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') { onText(JSON.parse(ev.data)); return; }
    ws.send('ack');
    const frame = parseFrame(ev.data);
    if (!frame) return;
    state.frame = frame; state.fresh = true; state.received++; state.dropped = frame.dropped;
    trails.sample(frame);
  };
  ws.onopen = () => setText('link', 'connected');
  ws.onclose = () => {
    setText('link', 'reconnecting…');
    state.idsSeq = -1;
    setTimeout(connect, 1000);
  };
}

function onText(msg) {
  if (msg.type === 'config') {
    state.config = msg;
    trails.step = msg.trail / TRAIL_POINTS;
    basemap.setOrigin(msg.origin);
    tiles = msg.tiles && msg.origin
      ? new Tiles(msg.tiles, $('tiles'), () => { state.moved = true; }) : null;
    state.moved = true;
    setText('ns', msg.ns);
  } else if (msg.type === 'health') {
    state.overlay.sensors = msg.sensors;
    showHealth(msg);
    state.moved = true;
  }
}

function showHealth(msg) {
  const alive = msg.alive.length ? msg.alive.join(', ') : 'none';
  const serving = msg.serving || [];
  const lines = [`tracker alive: ${alive}`,
                 `${serving.length} of ${msg.alive.length} instances serve the picture`];
  for (const s of msg.services) {
    lines.push(`${s.instance}: ${s.clock} ${s.tracks} tracks, ` +
               `${s.rejects_per_s.toFixed(1)} rejects/s, ${s.frames_missed} frames missed`);
  }
  if (!msg.services.length) lines.push('no status reply');
  const el = $('health');
  el.textContent = lines.join('\n');
  const missing = msg.alive.some((name) => !serving.includes(name));
  el.className = !msg.alive.length ? 'down' : (serving.length && missing ? 'warn' : 'ok');
}

// ---------------------------------------------------------------- drawing
function resize() {
  view.dpr = window.devicePixelRatio || 1;
  view.width = canvas.clientWidth; view.height = canvas.clientHeight;
  canvas.width = Math.round(view.width * view.dpr);
  canvas.height = Math.round(view.height * view.dpr);
  state.moved = true;
}

function fitToData() {
  const f = state.frame;
  let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
  const take = (x, y) => { x0 = Math.min(x0, x); x1 = Math.max(x1, x); y0 = Math.min(y0, y); y1 = Math.max(y1, y); };
  if (f) for (let i = 0; i < f.n; i++) take(f.pos[3 * i], f.pos[3 * i + 1]);
  for (const s of state.overlay.sensors) take(s.pos[0], s.pos[1]);
  for (const ic of f ? f.interceptors : []) take(ic.pos[0], ic.pos[1]);
  if (x0 <= x1) view.fit(x0 - 500, y0 - 500, x1 + 500, y1 + 500);
}

function tick(now) {
  requestAnimationFrame(tick);
  if (!state.fresh && !state.moved) return;
  const start = performance.now();
  const f = state.frame;
  if (f && state.follow && f !== state.fitFrame && now - state.fitted > FIT_PERIOD) {
    fitToData(); state.fitted = now; state.fitFrame = f;
  }
  state.overlay.interceptors = f ? f.interceptors : [];
  state.overlay.selectedRow = f && state.selected ? f.rowOf(state.selected) : -1;
  if (tiles && state.basemap) tiles.draw(view, state.config.origin);
  drawFrame(ctx, raster, view, f, trails, state.overlay, {
    labels: state.labels, trails: state.trails, origin: state.config.origin,
    basemap: state.basemap ? basemap : null, transparent: Boolean(tiles && state.basemap) });
  if (state.fresh) {
    state.drawn.push(now);
    state.drawMs = 0.9 * state.drawMs + 0.1 * (performance.now() - start);
  }
  state.fresh = false; state.moved = false;
  if (f) {
    setText('track-count', String(f.n));
    setText('clock', f.t.toFixed(2));
  }
}

function hudLoop() {
  const now = performance.now();
  if (state.follow && state.frame !== state.fitFrame) state.moved = true; // the last frame fitted
  while (state.drawn.length && state.drawn[0] < now - 1000) state.drawn.shift();
  setText('fps', String(state.drawn.length));
  setText('draw-ms', state.drawMs.toFixed(1));
  setText('dropped', String(state.dropped));
  if (state.selected) showDetails(state.selected, state, false);
}

function setText(id, text) {
  const el = $(id);
  if (el && el.textContent !== text) el.textContent = text;
}

// ---------------------------------------------------------------- interaction
function pick(px, py) {
  const f = state.frame;
  if (!f) return null;
  let best = -1, bestD = 10 * 10;
  for (let i = 0; i < f.n; i++) {
    const dx = view.sx(f.pos[3 * i]) - px, dy = view.sy(f.pos[3 * i + 1]) - py;
    const d = dx * dx + dy * dy;
    if (d <= bestD) { bestD = d; best = i; }
  }
  return best >= 0 ? f.ids[best] : null;
}

function select(id) {
  state.selected = id;
  state.moved = true;
  $('details').hidden = !id;
  if (id) showDetails(id, state, true);
}

let drag = null;
canvas.addEventListener('pointerdown', (e) => {
  drag = { x: e.clientX, y: e.clientY, moved: false };
  canvas.setPointerCapture(e.pointerId);
});
canvas.addEventListener('pointermove', (e) => {
  showCursor(e.clientX, e.clientY);
  if (!drag) return;
  const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
  if (!drag.moved && dx * dx + dy * dy < 9) return;
  drag.moved = true; state.follow = false;
  view.cx -= dx * view.mpp; view.cy += dy * view.mpp;
  drag.x = e.clientX; drag.y = e.clientY;
  state.moved = true; saveView();
});
canvas.addEventListener('pointerup', (e) => {
  if (drag && !drag.moved) select(pick(e.clientX, e.clientY));
  drag = null;
});
canvas.addEventListener('wheel', (e) => {
  e.preventDefault();
  state.follow = false;
  view.zoomAt(e.clientX, e.clientY, Math.exp(e.deltaY * 0.0015));
  state.moved = true; saveView();
}, { passive: false });
window.addEventListener('keydown', (e) => {
  if (e.key === 'f') { state.follow = true; state.fitted = -Infinity; state.moved = true; history.replaceState(null, '', ' '); }
  else if (e.key === 'l') { state.labels = { auto: 'all', all: 'none', none: 'auto' }[state.labels]; state.moved = true; }
  else if (e.key === 't') { state.trails = !state.trails; state.moved = true; }
  else if (e.key === 'g') { state.basemap = !state.basemap; state.moved = true; }
  else if (e.key === 'Escape') select(null);
  else if (e.key === '+' || e.key === '=') zoomKey(1 / 1.5);
  else if (e.key === '-') zoomKey(1.5);
});
$('detail-close').addEventListener('click', () => select(null));

function zoomKey(factor) {
  state.follow = false;
  view.zoomAt(view.width / 2, view.height / 2, factor);
  state.moved = true; saveView();
}

function showCursor(px, py) {
  const x = view.wx(px), y = view.wy(py);
  let text = `E ${x.toFixed(0)} m  N ${y.toFixed(0)} m`;
  if (state.config.origin) {
    const [lat, lon] = enuToGeodetic(state.config.origin, x, y, 0);
    text += `  ${formatLatLon(lat, lon)}`;
  }
  setText('cursor', text);
}

// The view lives in the address (#x,y,metres-per-pixel) so that it can be bookmarked.
let saveTimer = 0;
function saveView() {
  clearTimeout(saveTimer);
  saveTimer = setTimeout(() => history.replaceState(
    null, '', `#${view.cx.toFixed(1)},${view.cy.toFixed(1)},${view.mpp.toPrecision(4)}`), 200);
}

function loadView() {
  const parts = location.hash.slice(1).split(',').map(Number);
  if (parts.length === 3 && parts.every(Number.isFinite) && parts[2] > 0) {
    [view.cx, view.cy, view.mpp] = parts;
    state.follow = false;
  }
}

$('legend').innerHTML = STATUS_NAMES.map((s, i) =>
  `<span class="swatch s${i}"></span>${s}`).join(' ');
window.addEventListener('resize', resize);
window.addEventListener('hashchange', () => { loadView(); state.moved = true; });
resize();
loadView();
connect();
setInterval(hudLoop, 250);
requestAnimationFrame(tick);
