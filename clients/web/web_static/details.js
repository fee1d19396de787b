// The details panel of the selected track: its `tracks/<id>` state (GET /api/tracks/<id>,
// a get on the service through track-web) and its row of the newest frame.
import { enuToGeodetic, formatLatLon } from './geo.js';
import { STATUS_NAMES } from './render.js';

const REFRESH_MS = 1000;
let shown = { id: null, data: null, at: 0, pending: false };

const esc = (s) => String(s).replace(/[&<>"]/g, (c) => `&#${c.charCodeAt(0)};`);
const num = (v, d = 1) => (typeof v === 'number' ? v.toFixed(d) : '–');
// covariance entries in at most 7 characters: the 9 x 9 table of a CA state fits the panel
const sci = (v) => (Math.abs(v) >= 1e4 || (v !== 0 && Math.abs(v) < 1e-2)
  ? v.toExponential(1).replace('e+', 'e') : v.toFixed(Math.abs(v) >= 100 ? 0 : 2));

export function showDetails(id, state, now) {
  document.getElementById('detail-id').textContent = id;
  if (shown.id !== id) shown = { id, data: null, at: 0, pending: false };
  render(state);
  if (shown.pending || (!now && performance.now() - shown.at < REFRESH_MS)) return;
  shown.pending = true;
  fetch(`/api/tracks/${encodeURIComponent(id)}`)
    .then((r) => r.json())
    .then((data) => { if (shown.id === id) { shown.data = data; render(state); } })
    .catch((err) => { if (shown.id === id) shown.data = { error: String(err) }; })
    .finally(() => { shown.pending = false; shown.at = performance.now(); });
}

function render(state) {
  const f = state.frame, row = f ? f.rowOf(shown.id) : -1;
  const parts = [];
  if (row < 0) parts.push('<p class="gone">not in the latest frame</p>');
  else {
    const [x, y, z] = f.pos.subarray(3 * row, 3 * row + 3);
    const [vx, vy, vz] = f.vel.subarray(3 * row, 3 * row + 3);
    const course = ((Math.atan2(vx, vy) * 180) / Math.PI + 360) % 360;
    parts.push(`<table>
      <tr><th>status</th><td>${esc(STATUS_NAMES[f.status[row]] || 'unknown')}</td></tr>
      <tr><th>position</th><td>E ${num(x)} N ${num(y)} U ${num(z)} m</td></tr>`);
    if (state.config.origin) {
      const [lat, lon, h] = enuToGeodetic(state.config.origin, x, y, z);
      parts.push(`<tr><th>lat/lon</th><td id="detail-latlon">${formatLatLon(lat, lon)}, ${num(h)} m</td></tr>`);
    }
    parts.push(`<tr><th>velocity</th><td>${num(vx)} ${num(vy)} ${num(vz)} m/s</td></tr>
      <tr><th>speed</th><td>${num(Math.hypot(vx, vy, vz))} m/s, course ${num(course)}°</td></tr>
      <tr><th>sigma</th><td>${num(f.sigma[row])} m (at t ${num(f.t, 2)})</td></tr></table>`);
  }
  const d = shown.data;
  if (!d) parts.push('<p>asking the service…</p>');
  else if (d.error) parts.push(`<p class="gone">${esc(d.error)}</p>`);
  else parts.push(filtered(d));
  document.getElementById('detail-body').innerHTML = parts.join('');
}

function filtered(d) {
  const out = [`<h3>last update (tracks/${esc(d.id)})</h3><table>
    <tr><th>t</th><td>${num(d.t, 3)} s, age ${num(d.age, 2)} s</td></tr>
    <tr><th>updates</th><td>${esc(d.updates)}</td></tr>
    <tr><th>NIS</th><td>${num(d.nis, 2)}</td></tr>`];
  if (typeof d.model === 'string') out.push(`<tr><th>model</th><td>${esc(d.model)}</td></tr>`);
  out.push('</table>');
  if (d.model && typeof d.model === 'object') {
    out.push('<h3>model probabilities</h3><table class="probs">');
    for (const [name, p] of Object.entries(d.model)) {
      out.push(`<tr><th>${esc(name)}</th><td><span class="bar" style="width:${(100 * p).toFixed(0)}px"></span> ${num(p, 3)}</td></tr>`);
    }
    out.push('</table>');
  }
  const n = d.x.length, dim = dimension(d);
  const names = ['x', 'y', 'z'].slice(0, dim);
  const labels = [...names, ...names.map((a) => `v${a}`), ...names.map((a) => `a${a}`)].slice(0, n);
  out.push('<h3>state and covariance</h3><div class="scroll"><table class="matrix" id="detail-matrix"><tr><th></th><th>value</th><th>σ</th>');
  labels.forEach((l) => out.push(`<th>${l}</th>`));
  out.push('</tr>');
  for (let i = 0; i < n; i++) {
    out.push(`<tr><th>${labels[i]}</th><td>${num(d.x[i], 2)}</td><td>${num(Math.sqrt(Math.max(d.P[i * n + i], 0)), 2)}</td>`);
    for (let j = 0; j < n; j++) out.push(`<td>${sci(d.P[i * n + j])}</td>`);
    out.push('</tr>');
  }
  out.push('</table></div>');
  return out.join('');
}

/** 3 if the state starts with pos (3) then vel (3), else 2 (x = [x, y, vx, vy, ...]). */
function dimension(d) {
  const same = (a, b) => a === b;
  if (d.x.length % 3 === 0 && [0, 1, 2].every((k) => same(d.x[k], d.pos[k]) && same(d.x[3 + k], d.vel[k]))) return 3;
  return 2;
}
