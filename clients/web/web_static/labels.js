// Labels that do not overlap, placed as a scope places its data blocks: each label tries
// the four corners around its mark (right-above, right-below, left-above, left-below) in
// that order and takes the first free one; a label with no free corner is not drawn
// (thinned). Labels are placed in priority order (the selected track, sensors,
// interceptors, then tracks), against the marks' own boxes reserved first. Boxes are
// kept in a grid of cells so that each test looks at its neighbours only.
const CELL = 48; // px

export class Placer {
  constructor(width, height) {
    this.w = width; this.h = height; this.cells = new Map(); this.placed = [];
  }
  key(cx, cy) { return cx * 65536 + cy; }
  cellsOf(b, fn) {
    for (let cx = Math.floor(b[0] / CELL); cx <= Math.floor(b[2] / CELL); cx++) {
      for (let cy = Math.floor(b[1] / CELL); cy <= Math.floor(b[3] / CELL); cy++) {
        if (fn(this.key(cx, cy)) === false) return false;
      }
    }
    return true;
  }
  free(b) {
    if (b[0] < 0 || b[1] < 0 || b[2] > this.w || b[3] > this.h) return false;
    return this.cellsOf(b, (k) => {
      const list = this.cells.get(k);
      if (!list) return true;
      for (const o of list) if (b[0] < o[2] && o[0] < b[2] && b[1] < o[3] && o[1] < b[3]) return false;
      return true;
    });
  }
  reserve(b) {
    this.cellsOf(b, (k) => { const l = this.cells.get(k); if (l) l.push(b); else this.cells.set(k, [b]); });
  }
  /** Place a label of `width` x `height` px beside the mark at (x, y); its box or null. */
  place(x, y, width, height, gap = 6) {
    const options = [[x + gap, y - gap - height], [x + gap, y + gap],
                     [x - gap - width, y - gap - height], [x - gap - width, y + gap]];
    for (const [lx, ly] of options) {
      const b = [lx, ly, lx + width, ly + height];
      if (this.free(b)) { this.reserve(b); this.placed.push(b); return b; }
    }
    return null;
  }
}

/** Draw `items` ({text, x, y, font, colour}) in order where they fit; returns how many
 *  were drawn. `marks`: boxes of symbols that labels must not cover. */
export function drawLabels(ctx, width, height, marks, items) {
  const placer = new Placer(width, height);
  for (const m of marks) placer.reserve(m);
  ctx.textBaseline = 'top'; ctx.textAlign = 'left';
  let drawn = 0, font = '';
  for (const it of items) {
    if (it.font !== font) { ctx.font = it.font; font = it.font; }
    const b = placer.place(it.x, it.y, ctx.measureText(it.text).width + 2, it.size + 2);
    if (!b) continue;
    ctx.fillStyle = it.colour; ctx.fillText(it.text, b[0] + 1, b[1] + 1);
    drawn++;
  }
  return drawn;
}
