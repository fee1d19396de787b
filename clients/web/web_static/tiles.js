// An operator's own map tiles (`track-web --tiles URL`, XYZ in Web Mercator), drawn on a
// canvas under the map: each tile's corners placed by their latitude and longitude in the
// East-North-Up plane of the origin (a tile a few tens of km wide is as good as flat
// there). Nothing is fetched unless the operator gave a URL.
import { enuToGeodetic, geodeticToEnu } from './geo.js';

const EQUATOR_M_PER_PX = 156543.03392; // Web Mercator metres per pixel at zoom 0
const MAX_ZOOM = 19;

export function tileOf(lat, lon, z) {
  const k = 2 ** z, r = (lat * Math.PI) / 180;
  return [((lon + 180) / 360) * k, ((1 - Math.asinh(Math.tan(r)) / Math.PI) / 2) * k];
}

export function cornerOf(x, y, z) {
  const k = 2 ** z;
  return [(Math.atan(Math.sinh(Math.PI * (1 - (2 * y) / k))) * 180) / Math.PI, (x / k) * 360 - 180];
}

export class Tiles {
  constructor(template, canvas, changed) {
    this.template = template; this.canvas = canvas; this.changed = changed;
    this.images = new Map(); this.key = '';
  }
  url(z, x, y) { return this.template.replace('{z}', z).replace('{x}', x).replace('{y}', y); }
  image(z, x, y) {
    const key = `${z}/${x}/${y}`;
    let img = this.images.get(key);
    if (!img) {
      img = new Image(); img.referrerPolicy = 'no-referrer';
      img.onload = () => { this.key = ''; this.changed(); };
      img.src = this.url(z, x, y);
      this.images.set(key, img);
    }
    return img.complete && img.naturalWidth ? img : null;
  }
  draw(view, origin) {
    const key = `${view.width},${view.height},${view.dpr},${view.cx},${view.cy},${view.mpp}`;
    if (key === this.key) return;
    this.key = key;
    const c = this.canvas, k = view.dpr;
    if (c.width !== Math.round(view.width * k)) c.width = Math.round(view.width * k);
    if (c.height !== Math.round(view.height * k)) c.height = Math.round(view.height * k);
    const ctx = c.getContext('2d');
    ctx.setTransform(1, 0, 0, 1, 0, 0); ctx.clearRect(0, 0, c.width, c.height);
    ctx.setTransform(k, 0, 0, k, 0, 0);
    const [lat0] = origin;
    const z = Math.min(Math.max(Math.round(Math.log2(
      (EQUATOR_M_PER_PX * Math.cos((lat0 * Math.PI) / 180)) / view.mpp)), 0), MAX_ZOOM);
    const corners = [[0, 0], [view.width, 0], [0, view.height], [view.width, view.height]]
      .map(([px, py]) => enuToGeodetic(origin, view.wx(px), view.wy(py), 0))
      .map(([la, lo]) => tileOf(la, lo, z));
    const xs = corners.map((p) => p[0]), ys = corners.map((p) => p[1]);
    const n = 2 ** z;
    for (let x = Math.floor(Math.min(...xs)); x <= Math.floor(Math.max(...xs)); x++) {
      for (let y = Math.max(Math.floor(Math.min(...ys)), 0); y <= Math.min(Math.floor(Math.max(...ys)), n - 1); y++) {
        const img = this.image(z, ((x % n) + n) % n, y);
        if (!img) continue;
        const [la0, lo0] = cornerOf(x, y, z), [la1, lo1] = cornerOf(x + 1, y + 1, z);
        const [e0, n0] = geodeticToEnu(origin, la0, lo0, 0), [e1, n1] = geodeticToEnu(origin, la1, lo1, 0);
        const sx = view.sx(e0), sy = view.sy(n0);
        ctx.drawImage(img, sx, sy, view.sx(e1) - sx, view.sy(n1) - sy);
      }
    }
  }
}
