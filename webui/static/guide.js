// How each turn is made, for someone who has never done it: the table and the block seen from above, the
// device on it, where the two hands hold it and which way it goes round; with the same in three short steps.

import { s } from "./dom.js";

/** What to do for each turn, in plain words: where to hold, how to turn, where to put it back. */
export const TURN_STEPS = {
  x: [
    "Hold it by its left and right sides, where the red X arrow points.",
    "Lift it a little and roll it over once around the red line, until it is face up again.",
    "Put it back against the block and let go.",
  ],
  y: [
    "Hold it by the edge against the block and the opposite edge, where the green Y arrow points.",
    "Lift it a little and roll it over once around the green line, until it is face up again.",
    "Put it back against the block and let go.",
  ],
  z: [
    "Keep it flat on the table, face up, with a hand on each side.",
    "Spin it once round on the table, like a dial, until it faces the block again.",
    "Push it back against the block and let go.",
  ],
};

/** The whole turn in one sentence, under the headline. */
export const TURN_SENTENCE = {
  x: "Hold it by its left and right sides, roll it over once around the red line, and put it back against the block.",
  y: "Hold it by the edge at the block and the opposite edge, roll it over once around the green line, and put it back against the block.",
  z: "Keep it flat on the table, spin it once round like a dial, and push it back against the block.",
};

/** One line per turn for the overview before Start. */
export const TURN_SUMMARY = {
  x: "Roll it over around the red line",
  y: "Roll it over around the green line",
  z: "Spin it flat on the table",
};

/** The turn in the fewest words, for the headline. */
export const TURN_SHORT = { x: "roll it over", y: "roll it over sideways", z: "spin it flat" };

/** A hand seen from above, fingers pointing up at (0, 0) before it is placed with ``transform``. */
function hand(transform) {
  return s("g", { class: "hand", transform },
    s("path", { d: "M-17 34 V-4 Q-17 -26 0 -26 Q17 -26 17 -4 V34 Z", class: "palm" }),
    s("path", { d: "M17 12 Q30 2 34 14 Q33 22 17 28 Z", class: "thumb" }),
    s("path", { d: "M-8 -24 V-8 M0 -26 V-8 M8 -24 V-8", class: "finger-lines" }));
}

/** The device seen from above with its printed axes, centred on (cx, cy). */
function device(cx, cy) {
  const w = 116;
  const ht = 108;
  return s("g", { class: "device-face" },
    s("rect", { x: cx - w / 2, y: cy - ht / 2, width: w, height: ht, rx: 14, class: "case" }),
    s("line", { x1: cx, y1: cy, x2: cx + 36, y2: cy, class: "axis-line ax-x" }),
    s("path", { d: `M${cx + 44} ${cy} l-11 -6 v12 z`, class: "axis-head ax-x" }),
    s("text", { x: cx + 30, y: cy + 24, class: "axis-label small ax-x" }, "X"),
    s("line", { x1: cx, y1: cy, x2: cx, y2: cy - 34, class: "axis-line ax-y" }),
    s("path", { d: `M${cx} ${cy - 42} l-6 11 h12 z`, class: "axis-head ax-y" }),
    s("text", { x: cx - 22, y: cy - 22, class: "axis-label small ax-y" }, "Y"),
    s("circle", { cx, cy, r: 7, class: "axis-ring ax-z" }),
    s("circle", { cx, cy, r: 2.6, class: "axis-dot ax-z" }));
}

/** The picture of one turn. ``small`` drops the words in the picture (the overview's thumbnails). */
export function turnGuide(axis, { small = false } = {}) {
  const cx = 180;
  const cy = 128;
  const parts = [
    s("rect", { x: 4, y: 4, width: 352, height: 272, rx: 16, class: "table" }),
    s("rect", { x: 40, y: 182, width: 280, height: 28, rx: 5, class: "block" }),
    small ? null : s("text", { x: 90, y: 202, class: "block-label" }, "block"),
    small ? null : s("text", { x: 20, y: 262, class: "table-label" }, "table"),
    device(cx, cy),
  ];
  if (axis === "x") {
    parts.push(
      s("line", { x1: cx - 150, y1: cy, x2: cx + 150, y2: cy, class: "guide-axis ax-x" }),
      hand(`translate(${cx - 78} ${cy}) rotate(90)`), hand(`translate(${cx + 78} ${cy}) rotate(-90) scale(-1 1)`),
      s("path", { d: `M${cx + 118} ${cy + 40} C${cx + 150} ${cy + 20} ${cx + 150} ${cy - 40} ${cx + 118} ${cy - 60}`, class: "turn-arrow ax-x" }),
      s("path", { d: `M${cx + 112} ${cy - 64} l14 -2 l-6 13 z`, class: "turn-head ax-x" }));
  } else if (axis === "y") {
    parts.push(
      s("line", { x1: cx, y1: cy - 112, x2: cx, y2: cy + 64, class: "guide-axis ax-y" }),
      hand(`translate(${cx} ${cy - 74}) rotate(180)`), hand(`translate(${cx} ${cy + 74}) scale(-1 1)`),
      s("path", { d: `M${cx + 40} ${cy - 96} C${cx + 70} ${cy - 84} ${cx + 70} ${cy - 40} ${cx + 62} ${cy - 20}`, class: "turn-arrow ax-y" }),
      s("path", { d: `M${cx + 55} ${cy - 18} l14 -4 l-3 14 z`, class: "turn-head ax-y" }));
  } else {
    parts.push(
      hand(`translate(${cx - 70} ${cy - 30}) rotate(60)`), hand(`translate(${cx + 70} ${cy + 30}) rotate(-120)`),
      s("path", { d: `M${cx + 100} ${cy} A100 84 0 1 1 ${cx + 70} ${cy - 60}`, class: "turn-arrow ax-z" }),
      s("path", { d: `M${cx + 78} ${cy - 68} l4 14 l-14 -3 z`, class: "turn-head ax-z" }));
  }
  const label = `${TURN_SUMMARY[axis]}: ${TURN_STEPS[axis].join(" ")}`;
  return s("svg", { viewBox: "0 0 360 280", class: `turn-guide turn-guide-${axis}`, role: "img", "aria-label": label }, ...parts);
}
