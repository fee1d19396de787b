// The basemap under the tracks: Natural Earth coastlines and country borders (public
// domain; the world-atlas TopoJSON shipped in basemap/, decoded by topojson-client),
// drawn in the East-North-Up plane of the deployment's geodetic origin, at the level of
// detail of the zoom (1:110m, 1:50m, 1:10m, each file fetched from this server the first
// time a zoom needs it); the lat/lon graticule; range rings and the coverage circle of
// each sensor. Everything is drawn into the base layer of the raster, which is made again
// only when the view changes: the 30 Hz draw of the tracks does not pay for it.
import { centralAngle, enuToGeodetic, geodeticToEnu } from './geo.js';

// level of detail by the width of the view: coarser files for wider views
export const LEVELS = [
  { name: '110m', minSpan: 4e6 }, { name: '50m', minSpan: 6e5 }, { name: '10m', minSpan: 0 },
];
const HORIZON = 60; // degrees from the origin beyond which nothing is drawn (a plane of ENU)
export const COAST = '#7fa7d6';
export const BORDER = '#3e5068';
export const GRATICULE = '#1c2b44';
export const RING = '#1b2d44';
export const COVERAGE = '#2d4f6b';

/** Polylines in ENU metres: points xy, the first point of each line, each line's box. */
function project(origin, lines) {
  const xy = [], starts = [], boxes = [];
  for (const line of lines) {
    let run = 0;
    for (const [lon, lat] of line) {
      if (centralAngle(origin[0], origin[1], lat, lon) > HORIZON) { run = 0; continue; }
      const [e, n] = geodeticToEnu(origin, lat, lon, 0);
      if (run === 0) { starts.push(xy.length / 2); boxes.push(e, n, e, n); }
      const b = boxes.length - 4;
      boxes[b] = Math.min(boxes[b], e); boxes[b + 1] = Math.min(boxes[b + 1], n);
      boxes[b + 2] = Math.max(boxes[b + 2], e); boxes[b + 3] = Math.max(boxes[b + 3], n);
      xy.push(e, n); run++;
    }
  }
  starts.push(xy.length / 2);
  return { xy: new Float64Array(xy), starts: new Uint32Array(starts), boxes: new Float64Array(boxes) };
}

export class Basemap {
  /** `url(name)`: where the TopoJSON of a level is served; `changed()`: called when a
   *  level has come (the base layer must be drawn again). */
  constructor(url, changed) {
    this.url = url; this.changed = changed;
    this.origin = null; this.topologies = new Map(); this.projected = new Map();
    this.version = 0;
  }
  setOrigin(origin) {
    const key = origin ? origin.join(',') : '';
    if (key === (this.origin ? this.origin.join(',') : '')) return;
    this.origin = origin; this.projected.clear(); this.topologies.clear(); this.version++;
  }
  /** The level for a view `span` metres wide, fetched when first needed. */
  wanted(span) { return LEVELS.find((l) => span >= l.minSpan).name; }
  /** Coast and border lines of the most detailed level at hand not finer than wanted. */
  lines(span) {
    if (!this.origin) return null;
    const want = this.wanted(span);
    this.load(want);
    const order = LEVELS.map((l) => l.name);
    const candidates = order.slice(0, order.indexOf(want) + 1).reverse();
    const ready = candidates.find((n) => this.projected.has(n) || this.topologies.get(n)
                                         instanceof Object && !(this.topologies.get(n) instanceof Promise));
    if (!ready) return null;
    if (!this.projected.has(ready)) {
      // projected once for this origin; the decoded file (tens of MB of JavaScript
      // objects for 1:10m) is let go, so that it does not weigh on every garbage collection
      const topo = this.topologies.get(ready), tj = window.topojson;
      const coast = tj.mesh(topo, topo.objects.land).coordinates;
      const borders = tj.mesh(topo, topo.objects.countries, (a, b) => a !== b).coordinates;
      this.projected.set(ready, { name: ready, coast: project(this.origin, coast),
                                  borders: project(this.origin, borders) });
      this.topologies.set(ready, 'projected');
    }
    return this.projected.get(ready);
  }
  load(name) {
    if (this.topologies.has(name)) return;
    const pending = fetch(this.url(name)).then((r) => r.json()).then((topo) => {
      this.topologies.set(name, topo); this.version++; this.changed();
    }).catch(() => this.topologies.delete(name));
    this.topologies.set(name, pending);
  }
}

/** Draw polylines into the raster through the device map m (only boxes in view). */
export function drawLines(raster, m, lines, colour, bounds) {
  const { xy, starts, boxes } = lines, { a, bx, by } = m;
  const [x0, y0, x1, y1] = bounds;
  for (let l = 0; l + 1 < starts.length; l++) {
    if (boxes[4 * l] > x1 || boxes[4 * l + 2] < x0 || boxes[4 * l + 1] > y1
        || boxes[4 * l + 3] < y0) continue;
    let px = xy[2 * starts[l]] * a + bx, py = by - xy[2 * starts[l] + 1] * a;
    for (let i = starts[l] + 1; i < starts[l + 1]; i++) {
      const qx = xy[2 * i] * a + bx, qy = by - xy[2 * i + 1] * a;
      if (Math.abs(qx - px) + Math.abs(qy - py) >= 1 || i + 1 === starts[l + 1]) {
        raster.line(px, py, qx, qy, colour);
        px = qx; py = qy;
      }
    }
  }
}

const DEGREE_STEPS = [0.01, 0.02, 0.05, 0.1, 0.2, 0.25, 0.5, 1, 2, 5, 10, 15, 30];

/** The graticule of a view: parallels and meridians every `step` degrees as ENU
 *  polylines, with where each meets the bottom (meridians) or right (parallels) edge. */
export function graticule(origin, view, targetPx = 160) {
  const corners = [[0, 0], [view.width, 0], [0, view.height], [view.width, view.height],
                   [view.width / 2, 0], [view.width / 2, view.height], [0, view.height / 2],
                   [view.width, view.height / 2]]
    .map(([px, py]) => enuToGeodetic(origin, view.wx(px), view.wy(py), 0));
  const lats = corners.map((c) => c[0]), lons = corners.map((c) => c[1]);
  const lat0 = Math.max(Math.min(...lats), -85), lat1 = Math.min(Math.max(...lats), 85);
  let lon0 = Math.min(...lons), lon1 = Math.max(...lons);
  if (lon1 - lon0 > 180) { lon0 = -180; lon1 = 180; } // the view spans the antimeridian
  const perPx = (view.mpp * targetPx) / 111320;
  const step = DEGREE_STEPS.find((s) => s >= perPx) || 30;
  const lines = [], samples = 48;
  const along = (fixed, from, to, isLat) => {
    const pts = [];
    for (let k = 0; k <= samples; k++) {
      const v = from + ((to - from) * k) / samples;
      const [lat, lon] = isLat ? [fixed, v] : [v, fixed];
      if (centralAngle(origin[0], origin[1], lat, lon) > HORIZON) continue;
      pts.push(geodeticToEnu(origin, lat, lon, 0));
    }
    return pts;
  };
  for (let lat = Math.ceil(lat0 / step) * step; lat <= lat1; lat += step) {
    lines.push({ kind: 'lat', value: lat, pts: along(lat, lon0 - step, lon1 + step, true) });
  }
  for (let lon = Math.ceil(lon0 / step) * step; lon <= lon1; lon += step) {
    lines.push({ kind: 'lon', value: lon, pts: along(lon, lat0 - step, lat1 + step, false) });
  }
  return { step, lines };
}

export function formatDegrees(value, step, kind) {
  const digits = step >= 1 ? 0 : step >= 0.1 ? 1 : 2;
  const v = ((value + 540) % 360) - 180;
  const shown = kind === 'lat' ? value : v;
  const hemi = kind === 'lat' ? (shown >= 0 ? 'N' : 'S') : (shown >= 0 ? 'E' : 'W');
  return `${Math.abs(shown).toFixed(digits)}°${shown === 0 ? '' : hemi}`;
}
