// East-North-Up metres about a geodetic origin -> WGS-84 latitude, longitude (degrees)
// and height (m): ENU -> ECEF by the local rotation, ECEF -> geodetic by the usual
// fixed-point iteration on latitude (Hofmann-Wellenhof et al., GNSS, 2008, sec. 10.2.1).
const A = 6378137.0;                 // WGS-84 semi-major axis, m
const F = 1 / 298.257223563;         // flattening
const E2 = F * (2 - F);              // first eccentricity squared
const RAD = Math.PI / 180;

export function geodeticToEcef(latDeg, lonDeg, h) {
  const lat = latDeg * RAD, lon = lonDeg * RAD;
  const n = A / Math.sqrt(1 - E2 * Math.sin(lat) ** 2);
  return [(n + h) * Math.cos(lat) * Math.cos(lon), (n + h) * Math.cos(lat) * Math.sin(lon),
          (n * (1 - E2) + h) * Math.sin(lat)];
}

export function enuToGeodetic(origin, e, n, u) {
  const [lat0, lon0, h0] = origin;
  const [x0, y0, z0] = geodeticToEcef(lat0, lon0, h0);
  const sp = Math.sin(lat0 * RAD), cp = Math.cos(lat0 * RAD);
  const sl = Math.sin(lon0 * RAD), cl = Math.cos(lon0 * RAD);
  const x = x0 - sl * e - sp * cl * n + cp * cl * u;
  const y = y0 + cl * e - sp * sl * n + cp * sl * u;
  const z = z0 + cp * n + sp * u;
  const p = Math.hypot(x, y);
  let lat = Math.atan2(z, p * (1 - E2)), h = 0;
  for (let i = 0; i < 6; i++) {
    const nn = A / Math.sqrt(1 - E2 * Math.sin(lat) ** 2);
    h = Math.abs(Math.cos(lat)) > 1e-9 ? p / Math.cos(lat) - nn : Math.abs(z) - nn * (1 - E2);
    lat = Math.atan2(z, p * (1 - E2 * nn / (nn + h)));
  }
  return [lat / RAD, Math.atan2(y, x) / RAD, h];
}

export function formatLatLon(lat, lon) {
  const ns = lat >= 0 ? 'N' : 'S', ew = lon >= 0 ? 'E' : 'W';
  return `${Math.abs(lat).toFixed(6)}° ${ns} ${Math.abs(lon).toFixed(6)}° ${ew}`;
}

/** WGS-84 latitude, longitude (degrees), height (m) -> East-North-Up metres about
 *  `origin`, by ECEF and the local rotation (the inverse of enuToGeodetic's first step). */
export function geodeticToEnu(origin, latDeg, lonDeg, h) {
  const [lat0, lon0, h0] = origin;
  const [x0, y0, z0] = geodeticToEcef(lat0, lon0, h0);
  const [x, y, z] = geodeticToEcef(latDeg, lonDeg, h);
  const dx = x - x0, dy = y - y0, dz = z - z0;
  const sp = Math.sin(lat0 * RAD), cp = Math.cos(lat0 * RAD);
  const sl = Math.sin(lon0 * RAD), cl = Math.cos(lon0 * RAD);
  return [-sl * dx + cl * dy, -sp * cl * dx - sp * sl * dy + cp * dz,
          cp * cl * dx + cp * sl * dy + sp * dz];
}

/** The angle (degrees) between two places seen from the Earth's centre (a sphere). */
export function centralAngle(lat1, lon1, lat2, lon2) {
  const a = lat1 * RAD, b = lat2 * RAD, d = (lon2 - lon1) * RAD;
  const c = Math.sin(a) * Math.sin(b) + Math.cos(a) * Math.cos(b) * Math.cos(d);
  return Math.acos(Math.min(Math.max(c, -1), 1)) / RAD;
}
