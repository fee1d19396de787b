// Small pieces shared by the drawing modules: colours as ImageData pixels, "nice"
// lengths and their text.
export const GRID_TEXT = '#5d6f86';

/** '#rrggbb' as the 32-bit pixel of an ImageData on a little-endian machine. */
export function pixel(hex) {
  const v = parseInt(hex.slice(1), 16);
  return (0xff000000 | ((v & 0xff) << 16) | (v & 0xff00) | (v >> 16)) >>> 0;
}

/** A "nice" length (1, 2 or 5 x 10^k) not above `x`. */
export function niceBelow(x) {
  const k = 10 ** Math.floor(Math.log10(x));
  const m = x / k;
  return (m >= 5 ? 5 : m >= 2 ? 2 : 1) * k;
}

export function formatDistance(m) {
  return m >= 1000 ? `${+(m / 1000).toPrecision(3)} km` : `${+m.toPrecision(3)} m`;
}

