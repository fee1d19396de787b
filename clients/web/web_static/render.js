// Drawing of one frame. The many marks (trails, uncertainty circles, velocity vectors and
// the dots of 10,000 tracks) are written as pixels into one ImageData with typed arrays
// and put on the canvas at once: without a GPU, Chromium's canvas costs about 6 us per
// filled rectangle and 7 us per arc (10,000 of each: 63 and 66 ms on this machine), the
// pixel loop a fraction of a microsecond per mark. The few marks with text or antialiasing
// (labels, sensors, interceptors, the selection, scale bar) are drawn by the canvas on top.

import { BORDER, COAST, drawLines } from './basemap.js';
import { drawLabels as placeLabels } from './labels.js';
import {
  drawGraticule, drawGraticuleText, drawRings, drawRingText, graticuleOf, sensorKey,
} from './mapdraw.js';
import { formatDistance, GRID_TEXT, niceBelow, pixel } from './paint.js';

export { formatDistance, niceBelow };

export const STATUS_NAMES = ['tentative', 'confirmed', 'coasting'];
export const STATUS_COLORS = ['#f5c542', '#4ade80', '#94a3b8', '#60a5fa']; // last: unknown
const BACKGROUND = '#0b1320';
const GRID = '#17243a';
const TRAIL = '#2f6f8f';
const VECTOR = '#c8d2e0';
const SIGMA = '#3b5f99';
const INTERCEPTOR = '#f472b6';
const SENSOR = '#e2e8f0';
const LABEL = '#cbd5e1';
const SELECTED = '#ffffff';

/** Pixels of one frame: lines, squares and circles written into an ImageData. */
export class Raster {
  constructor() {
    this.w = 0; this.h = 0; this.image = null; this.px = null; this.t0 = 0; this.t1 = 1;
    this.geo = null; this.geoKey = ''; this.base = null; this.baseKey = '';
  }
  /** Start a picture on the base layer: the geography (background, grid or graticule,
   *  basemap, sensor rings), kept for `geoKey` and made by `drawGeo` when it changed,
   *  under what `drawOver` adds (the trail history), kept for `key`. Each layer is made
   *  again only when its own key changed: a new trail sample copies the geography
   *  instead of drawing it. Returns whether the base layer was made again. */
  begin(ctx, w, h, geoKey, drawGeo, key, drawOver) {
    if (w !== this.w || h !== this.h) {
      this.w = w; this.h = h;
      this.image = ctx.createImageData(w, h);
      this.px = new Uint32Array(this.image.data.buffer);
      this.geo = new Uint32Array(w * h); this.base = new Uint32Array(w * h);
      this.geoKey = ''; this.baseKey = '';
    }
    let fresh = false; // px holds the geography just drawn
    if (geoKey !== this.geoKey) {
      drawGeo();
      this.geo.set(this.px); this.geoKey = geoKey; this.baseKey = ''; fresh = true;
    }
    if (key !== this.baseKey) {
      if (!fresh) this.px.set(this.geo);
      drawOver();
      this.base.set(this.px); this.baseKey = key;
      return true;
    }
    this.px.set(this.base);
    return false;
  }
  end(ctx) { ctx.putImageData(this.image, 0, 0); }
  hline(y, c) { if (y >= 0 && y < this.h) this.px.fill(c, y * this.w, (y + 1) * this.w); }
  vline(x, c) {
    if (x < 0 || x >= this.w) return;
    for (let i = x; i < this.px.length; i += this.w) this.px[i] = c;
  }
  square(x, y, size, c) {
    const x0 = Math.max(Math.round(x - size / 2), 0), y0 = Math.max(Math.round(y - size / 2), 0);
    const x1 = Math.min(x0 + size, this.w), y1 = Math.min(y0 + size, this.h);
    for (let yy = y0; yy < y1; yy++) this.px.fill(c, yy * this.w + x0, yy * this.w + x1);
  }
  /** A one-pixel line, clipped to the raster (Liang-Barsky), stepped along its long axis. */
  line(x0, y0, x1, y1, c) {
    const w = this.w - 1, h = this.h - 1;
    let dx = x1 - x0, dy = y1 - y0;
    if (!(x0 >= 0 && x0 <= w && y0 >= 0 && y0 <= h && x1 >= 0 && x1 <= w && y1 >= 0 && y1 <= h)) {
      this.t0 = 0; this.t1 = 1;
      if (!(this.edge(-dx, x0) && this.edge(dx, w - x0) && this.edge(-dy, y0)
            && this.edge(dy, h - y0))) return;
      const t0 = this.t0, t1 = this.t1;
      x0 += t0 * dx; y0 += t0 * dy; dx *= t1 - t0; dy *= t1 - t0;
    }
    const steps = Math.ceil(Math.max(Math.abs(dx), Math.abs(dy))), px = this.px, W = this.w;
    const sx = steps ? dx / steps : 0, sy = steps ? dy / steps : 0;
    let x = x0 + 0.5, y = y0 + 0.5;
    for (let i = 0; i <= steps; i++, x += sx, y += sy) px[(y | 0) * W + (x | 0)] = c;
  }
  /** One edge of Liang-Barsky: narrows [t0, t1]; false when nothing is left. */
  edge(p, q) {
    if (p === 0) return q >= 0;
    const r = q / p;
    if (p < 0) { if (r > this.t1) return false; if (r > this.t0) this.t0 = r; }
    else { if (r < this.t0) return false; if (r < this.t1) this.t1 = r; }
    return true;
  }
  /** A one-pixel circle (midpoint algorithm); pixels outside the raster are skipped. */
  circle(cx, cy, r, c) {
    const x0 = Math.round(cx), y0 = Math.round(cy), W = this.w, H = this.h, px = this.px;
    let x = Math.round(r), y = 0, err = 1 - x;
    const inside = x0 - x >= 0 && x0 + x < W && y0 - x >= 0 && y0 + x < H;
    const put = inside ? (a, b) => { px[b * W + a] = c; }
      : (a, b) => { if (a >= 0 && a < W && b >= 0 && b < H) px[b * W + a] = c; };
    while (x >= y) {
      put(x0 + x, y0 + y); put(x0 - x, y0 + y); put(x0 + x, y0 - y); put(x0 - x, y0 - y);
      put(x0 + y, y0 + x); put(x0 - y, y0 + x); put(x0 + y, y0 - x); put(x0 - y, y0 - x);
      y++;
      if (err < 0) err += 2 * y + 1; else { x--; err += 2 * (y - x) + 1; }
    }
  }
}

export const LABEL_LIMIT = 80; // ids drawn when at most this many tracks are in view
const VECTOR_SECONDS = 20; // a velocity vector shows the way covered in this time
const DOT = 4; // px

/** World (ENU metres) <-> screen (CSS pixels): centre (cx, cy), `mpp` metres per CSS
 *  pixel; `dpr` device pixels per CSS pixel. */
export class View {
  constructor() {
    this.cx = 0; this.cy = 0; this.mpp = 50; this.width = 1; this.height = 1; this.dpr = 1;
  }
  sx(x) { return (x - this.cx) / this.mpp + this.width / 2; }
  sy(y) { return this.height / 2 - (y - this.cy) / this.mpp; }
  wx(px) { return this.cx + (px - this.width / 2) * this.mpp; }
  wy(py) { return this.cy + (this.height / 2 - py) * this.mpp; }
  zoomAt(px, py, factor) {
    const x = this.wx(px), y = this.wy(py);
    this.mpp = Math.min(Math.max(this.mpp * factor, 1e-3), 1e6);
    this.cx = x - (px - this.width / 2) * this.mpp;
    this.cy = y - (this.height / 2 - py) * this.mpp;
  }
  fit(x0, y0, x1, y1) {
    this.cx = (x0 + x1) / 2; this.cy = (y0 + y1) / 2;
    const span = Math.max((x1 - x0) / this.width, (y1 - y0) / this.height);
    this.mpp = Math.max(span * 1.15, 1);
  }
}

/** The history of every track, sampled every `step` s of simulation time, kept by id in
 *  slots of a ring of `points` positions (typed arrays; slots are reused). */
export class Trails {
  constructor(points) {
    this.points = points; this.cap = 0; this.step = 1;
    this.xy = new Float32Array(0); this.count = new Uint16Array(0);
    this.head = new Uint16Array(0);
    this.slotOf = new Map(); this.free = []; this.rowSlot = new Int32Array(0);
    this.lastIndex = -Infinity; this.lastT = -Infinity;
    this.version = 0; // changes whenever the history to draw changes
  }
  grow(cap) {
    const xy = new Float32Array(cap * this.points * 2), count = new Uint16Array(cap);
    const head = new Uint16Array(cap);
    xy.set(this.xy); count.set(this.count); head.set(this.head);
    for (let s = cap - 1; s >= this.cap; s--) this.free.push(s);
    Object.assign(this, { xy, count, head, cap });
  }
  remap(ids) {
    const kept = new Map(), rowSlot = new Int32Array(ids.length);
    for (let i = 0; i < ids.length; i++) {
      let s = this.slotOf.get(ids[i]);
      if (s === undefined) {
        if (!this.free.length) this.grow(Math.max(64, this.cap * 2));
        s = this.free.pop(); this.count[s] = 0; this.head[s] = 0;
      } else this.slotOf.delete(ids[i]);
      kept.set(ids[i], s); rowSlot[i] = s;
    }
    for (const s of this.slotOf.values()) this.free.push(s);
    this.slotOf = kept; this.rowSlot = rowSlot; this.version++;
  }
  clear() { this.count.fill(0); this.lastIndex = -Infinity; this.version++; }
  sample(frame) {
    if (frame.t < this.lastT) this.clear(); // the clock went back: a new run
    this.lastT = frame.t;
    const index = Math.floor(frame.t / this.step);
    if (index === this.lastIndex) return;
    this.lastIndex = index; this.version++;
    const { pos, n } = frame, K = this.points;
    for (let i = 0; i < n; i++) {
      const s = this.rowSlot[i], at = (s * K + this.head[s]) * 2;
      this.xy[at] = pos[3 * i]; this.xy[at + 1] = pos[3 * i + 1];
      this.head[s] = (this.head[s] + 1) % K;
      if (this.count[s] < K) this.count[s]++;
    }
  }
}

/** The affine map world -> device pixels of the raster: X = x a + bx, Y = by - y a. */
function deviceMap(view) {
  const k = view.dpr, a = k / view.mpp;
  return { a, bx: (view.width / 2) * k - view.cx * a, by: (view.height / 2) * k + view.cy * a };
}

export function drawFrame(ctx, raster, view, frame, trails, overlay, options) {
  const k = view.dpr, step = niceBelow(view.mpp * 160);
  const visible = frame ? markVisible(view, frame) : null;
  const m = deviceMap(view);
  const geo = options.origin ? options.origin : null;
  const base = geo && options.basemap ? options.basemap : null;
  const span = view.mpp * Math.max(view.width, view.height);
  const map = base ? base.lines(span) : null;
  const grat = geo ? graticuleOf(geo, view) : null;
  // the geography (background, grid or graticule, basemap, sensor rings) changes only
  // with the view, and the trail history every trail sample: each a layer kept, copied
  // under each frame (the 1:10m coastlines of a 300 km view are tens of thousands of
  // points; 10,000 trails of 16 points each are 150,000 line segments)
  const history = options.trails && frame;
  const geoKey = `${view.width},${view.height},${k},${view.cx},${view.cy},${view.mpp},` +
    `${geo ? geo.join(',') : ''},${base ? `${base.version},${map ? map.name : ''}` : ''},` +
    `${sensorKey(overlay.sensors)},${options.transparent ? 1 : 0}`;
  const key = `${geoKey},${history ? trails.version : -1}`;
  raster.begin(ctx, Math.round(view.width * k), Math.round(view.height * k), geoKey, () => {
    raster.px.fill(options.transparent ? 0 : pixel(BACKGROUND));
    if (grat) drawGraticule(raster, m, grat); else drawGrid(raster, view, step);
    if (map) {
      const bounds = [view.wx(0), view.wy(view.height), view.wx(view.width), view.wy(0)];
      drawLines(raster, m, map.borders, pixel(BORDER), bounds);
      drawLines(raster, m, map.coast, pixel(COAST), bounds);
    }
    drawRings(raster, m, overlay.sensors);
  }, key, () => {
    if (history) drawTrails(raster, m, frame, trails, visible);
  });
  if (frame) {
    if (options.trails) drawTrailHeads(raster, m, frame, trails, visible);
    drawSigma(raster, m, frame, visible);
    drawVectors(raster, m, frame, visible);
    drawDots(raster, m, Math.round(DOT * k), frame, visible);
  }
  raster.end(ctx);
  ctx.setTransform(k, 0, 0, k, 0, 0);
  if (grat) drawGraticuleText(ctx, view, grat); else drawGridText(ctx, view, step);
  drawRingText(ctx, view, overlay.sensors);
  const marks = [];
  drawSensors(ctx, view, overlay.sensors, marks);
  drawInterceptors(ctx, view, overlay.interceptors, frame, marks);
  const items = [];
  if (frame && overlay.selectedRow >= 0) drawSelected(ctx, view, frame, overlay.selectedRow, marks, items);
  for (const s of overlay.sensors) {
    items.push({ text: s.id, x: view.sx(s.pos[0]), y: view.sy(s.pos[1]), font: FONT, size: 11, colour: SENSOR });
  }
  for (const ic of overlay.interceptors) {
    items.push({ text: ic.id + (ic.captured ? ' (captured)' : ''), x: view.sx(ic.pos[0]),
                 y: view.sy(ic.pos[1]), font: FONT, size: 11, colour: INTERCEPTOR });
  }
  const inView = visible ? visible.length : 0;
  if (frame && (options.labels === 'all' || (options.labels === 'auto' && inView <= LABEL_LIMIT))) {
    for (let r = 0; r < visible.length; r++) { // the dots: no label covers another track
      const x = view.sx(frame.pos[3 * visible[r]]), y = view.sy(frame.pos[3 * visible[r] + 1]);
      marks.push([x - DOT / 2, y - DOT / 2, x + DOT / 2, y + DOT / 2]);
    }
    for (let r = 0; r < visible.length; r++) {
      const i = visible[r];
      if (i === overlay.selectedRow) continue;
      items.push({ text: frame.ids[i], x: view.sx(frame.pos[3 * i]), y: view.sy(frame.pos[3 * i + 1]),
                   font: FONT, size: 11, colour: LABEL });
    }
  }
  overlay.labelsDrawn = placeLabels(ctx, view.width, view.height, marks, items);
  overlay.labelsWanted = items.length;
  overlay.basemapLevel = map ? map.name : '';
  drawScaleBar(ctx, view);
  return inView;
}

const FONT = '11px sans-serif';

/** The rows within 40 px of the view. */
function markVisible(view, frame) {
  const { pos, n } = frame, rows = new Uint32Array(n), m = 40 * view.mpp;
  const x0 = view.wx(0) - m, x1 = view.wx(view.width) + m;
  const y0 = view.wy(view.height) - m, y1 = view.wy(0) + m;
  let count = 0;
  for (let i = 0; i < n; i++) {
    const x = pos[3 * i], y = pos[3 * i + 1];
    if (x > x0 && x < x1 && y > y0 && y < y1) rows[count++] = i;
  }
  return rows.subarray(0, count);
}

function gridLines(view, step, fn) {
  const x0 = view.wx(0), x1 = view.wx(view.width), y0 = view.wy(view.height), y1 = view.wy(0);
  for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) fn('x', x, view.sx(x));
  for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) fn('y', y, view.sy(y));
}

function drawGrid(raster, view, step) {
  const c = pixel(GRID), k = view.dpr;
  gridLines(view, step, (axis, _, p) => {
    if (axis === 'x') raster.vline(Math.round(p * k), c); else raster.hline(Math.round(p * k), c);
  });
}

/** Grid values along the bottom (east) and the right edge (north), clear of the panels. */
function drawGridText(ctx, view, step) {
  ctx.fillStyle = GRID_TEXT; ctx.font = '11px sans-serif'; ctx.textBaseline = 'bottom';
  ctx.textAlign = 'right';
  gridLines(view, step, (axis, v, p) => {
    const side = axis === 'x' ? (v < 0 ? ' W' : v > 0 ? ' E' : '') : (v < 0 ? ' S' : v > 0 ? ' N' : '');
    const text = formatDistance(Math.abs(v)) + side;
    if (axis === 'x' && p > 180) ctx.fillText(text, p - 3, view.height - 3);
    else if (axis === 'y' && p < view.height - 40) ctx.fillText(text, view.width - 4, p - 2);
  });
  ctx.textAlign = 'left';
}

/** The sampled history of every track (the base layer). */
function drawTrails(raster, m, frame, trails, rows) {
  const { xy, count, head, points: K } = trails, c = pixel(TRAIL);
  const { a, bx, by } = m;
  for (let r = 0; r < rows.length; r++) {
    const i = rows[r], s = trails.rowSlot[i], n = count[s];
    if (!n) continue;
    let j = (head[s] - n + K) % K, at = (s * K + j) * 2;
    let x = xy[at] * a + bx, y = by - xy[at + 1] * a;
    for (let q = 1; q < n; q++) {
      j = j + 1 === K ? 0 : j + 1; at = (s * K + j) * 2;
      const nx = xy[at] * a + bx, ny = by - xy[at + 1] * a;
      raster.line(x, y, nx, ny, c);
      x = nx; y = ny;
    }
  }
}

/** From each track's newest sample to where it is now (every frame). */
function drawTrailHeads(raster, m, frame, trails, rows) {
  const { xy, count, head, points: K } = trails, pos = frame.pos, c = pixel(TRAIL);
  const { a, bx, by } = m;
  for (let r = 0; r < rows.length; r++) {
    const i = rows[r], s = trails.rowSlot[i];
    if (!count[s]) continue;
    const at = (s * K + (head[s] + K - 1) % K) * 2;
    raster.line(xy[at] * a + bx, by - xy[at + 1] * a, pos[3 * i] * a + bx,
                by - pos[3 * i + 1] * a, c);
  }
}

function drawSigma(raster, m, frame, rows) {
  const { pos, sigma } = frame, c = pixel(SIGMA), limit = 2 * (raster.w + raster.h);
  const { a, bx, by } = m;
  for (let r = 0; r < rows.length; r++) {
    const i = rows[r], radius = sigma[i] * a;
    if (radius < 3 || radius > limit) continue;
    raster.circle(pos[3 * i] * a + bx, by - pos[3 * i + 1] * a, radius, c);
  }
}

function drawVectors(raster, m, frame, rows) {
  const { pos, vel } = frame, c = pixel(VECTOR), { a, bx, by } = m, s = VECTOR_SECONDS * a;
  for (let r = 0; r < rows.length; r++) {
    const i = rows[r], x = pos[3 * i] * a + bx, y = by - pos[3 * i + 1] * a;
    raster.line(x, y, x + vel[3 * i] * s, y - vel[3 * i + 1] * s, c);
  }
}

function drawDots(raster, m, size, frame, rows) {
  const { pos, status } = frame, { a, bx, by } = m, colors = STATUS_COLORS.map(pixel);
  for (let r = 0; r < rows.length; r++) {
    const i = rows[r];
    raster.square(pos[3 * i] * a + bx, by - pos[3 * i + 1] * a, size, colors[Math.min(status[i], 3)]);
  }
}

function drawSelected(ctx, view, frame, i, marks, items) {
  const x = view.sx(frame.pos[3 * i]), y = view.sy(frame.pos[3 * i + 1]);
  ctx.beginPath(); ctx.arc(x, y, 9, 0, 2 * Math.PI);
  ctx.strokeStyle = SELECTED; ctx.lineWidth = 2; ctx.stroke();
  marks.push([x - 10, y - 10, x + 10, y + 10]);
  items.push({ text: frame.ids[i], x, y, font: 'bold 12px sans-serif', size: 12, colour: SELECTED });
}

function drawSensors(ctx, view, sensors, marks) {
  ctx.fillStyle = SENSOR;
  for (const s of sensors) {
    const x = view.sx(s.pos[0]), y = view.sy(s.pos[1]);
    ctx.beginPath(); ctx.moveTo(x, y - 7); ctx.lineTo(x + 6, y + 5); ctx.lineTo(x - 6, y + 5);
    ctx.closePath(); ctx.fill();
    marks.push([x - 6, y - 7, x + 6, y + 5]);
  }
}

function drawInterceptors(ctx, view, interceptors, frame, marks) {
  for (const ic of interceptors) {
    const x = view.sx(ic.pos[0]), y = view.sy(ic.pos[1]);
    const row = frame && ic.target ? frame.rowOf(ic.target) : -1;
    if (row >= 0) {
      ctx.beginPath(); ctx.setLineDash([4, 4]); ctx.moveTo(x, y);
      ctx.lineTo(view.sx(frame.pos[3 * row]), view.sy(frame.pos[3 * row + 1]));
      ctx.strokeStyle = INTERCEPTOR; ctx.lineWidth = 1; ctx.stroke(); ctx.setLineDash([]);
    }
    ctx.beginPath();
    ctx.moveTo(x, y - 7); ctx.lineTo(x + 7, y); ctx.lineTo(x, y + 7); ctx.lineTo(x - 7, y);
    ctx.closePath();
    ctx.fillStyle = INTERCEPTOR; ctx.fill();
    marks.push([x - 7, y - 7, x + 7, y + 7]);
  }
}

function drawScaleBar(ctx, view) {
  const metres = niceBelow(view.mpp * 150), px = metres / view.mpp;
  const x = 16, y = view.height - 34;
  ctx.beginPath();
  ctx.moveTo(x, y - 5); ctx.lineTo(x, y); ctx.lineTo(x + px, y); ctx.lineTo(x + px, y - 5);
  ctx.strokeStyle = '#e2e8f0'; ctx.lineWidth = 2; ctx.stroke();
  ctx.fillStyle = '#e2e8f0'; ctx.font = '12px sans-serif'; ctx.textBaseline = 'bottom';
  ctx.fillText(formatDistance(metres), x + 4, y - 6);
}
