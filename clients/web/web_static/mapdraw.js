// The geography of the base layer and its text: the lat/lon graticule, sensors' range
// rings and coverage (the coastlines and borders are basemap.js's).
import { COVERAGE, formatDegrees, GRATICULE, graticule, RING } from './basemap.js';
import { formatDistance, GRID_TEXT, niceBelow, pixel } from './paint.js';

let gratKey = '', gratLines = null;

/** The graticule of the view, made again only when the view or origin changes. */
export function graticuleOf(origin, view) {
  const key = `${origin.join(',')},${view.width},${view.height},${view.cx},${view.cy},${view.mpp}`;
  if (key !== gratKey) {
    gratKey = key; gratLines = graticule(origin, view);
    gratLines.labels = graticuleLabels(view, gratLines);
  }
  return gratLines;
}

export function sensorKey(sensors) {
  return sensors.map((s) => `${s.id}:${s.pos[0]},${s.pos[1]},${s.reach || 0}`).join(';');
}

/** Range rings every "nice" step up to each sensor's coverage (the farthest range it
 *  has reported), the coverage circle brighter. */
function ringSteps(reach) {
  if (!(reach > 0)) return { step: 0, cover: 0 };
  const step = niceBelow(reach / 3);
  return { step, cover: Math.ceil(reach / step) * step };
}

export function drawRings(raster, m, sensors) {
  const ring = pixel(RING), cover = pixel(COVERAGE), { a, bx, by } = m;
  for (const s of sensors) {
    const r = ringSteps(s.reach);
    if (!r.step) continue;
    const x = s.pos[0] * a + bx, y = by - s.pos[1] * a;
    for (let d = r.step; d < r.cover; d += r.step) {
      if (d * a > 4) raster.circle(x, y, d * a, ring);
    }
    if (r.cover * a > 4) raster.circle(x, y, r.cover * a, cover);
  }
}

export function drawRingText(ctx, view, sensors) {
  ctx.fillStyle = GRID_TEXT; ctx.font = '10px sans-serif'; ctx.textBaseline = 'bottom';
  ctx.textAlign = 'center';
  for (const s of sensors) {
    const r = ringSteps(s.reach);
    if (!r.step || r.cover / view.mpp < 40) continue;
    const x = view.sx(s.pos[0]), y = view.sy(s.pos[1]);
    for (let d = r.step; d <= r.cover; d += r.step) {
      if (d / view.mpp > 30) ctx.fillText(formatDistance(d), x, y - d / view.mpp - 1);
    }
  }
  ctx.textAlign = 'left';
}

export function drawGraticule(raster, m, grat) {
  const c = pixel(GRATICULE), { a, bx, by } = m;
  for (const line of grat.lines) {
    const p = line.pts;
    for (let i = 1; i < p.length; i++) {
      raster.line(p[i - 1][0] * a + bx, by - p[i - 1][1] * a, p[i][0] * a + bx, by - p[i][1] * a, c);
    }
  }
}

/** Latitudes along the right edge, longitudes along the bottom, where each line meets it
 *  (found once per view: `graticuleOf` keeps them with the lines). */
function graticuleLabels(view, grat) {
  const out = [];
  for (const line of grat.lines) {
    let best = null, bestD = Infinity;
    for (const [e, n] of line.pts) {
      const px = view.sx(e), py = view.sy(n);
      const d = line.kind === 'lon' ? Math.abs(py - view.height) : Math.abs(px - view.width);
      const inside = line.kind === 'lon' ? px > 180 && px < view.width : py > 0 && py < view.height - 40;
      if (inside && d < bestD) { bestD = d; best = [px, py]; }
    }
    if (!best || bestD > 60) continue;
    const text = formatDegrees(line.value, grat.step, line.kind);
    out.push(line.kind === 'lon' ? [text, best[0] - 3, view.height - 3] : [text, view.width - 4, best[1] - 2]);
  }
  return out;
}

export function drawGraticuleText(ctx, view, grat) {
  ctx.fillStyle = GRID_TEXT; ctx.font = '11px sans-serif'; ctx.textBaseline = 'bottom';
  ctx.textAlign = 'right';
  for (const [text, x, y] of grat.labels) ctx.fillText(text, x, y);
  ctx.textAlign = 'left';
}

