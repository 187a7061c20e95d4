// The pictures of the wizard, as inline SVG: icons, the device with its printed axes, the turn
// animation, the stillness ring, the live angle gauge and the X/Y/Z tiles.

import { AXIS_LABEL, h, s } from "./dom.js";

// -- icons: 24x24, drawn with the current text colour ------------------------------------------
const ICON_PATHS = {
  check: ["M5 12.5l4.5 4.5L19 7.5"],
  cross: ["M6 6l12 12", "M18 6L6 18"],
  pass: ["M12 2.5a9.5 9.5 0 1 0 0 19a9.5 9.5 0 1 0 0-19", "M7 12.5l3.5 3.5L17 9"],
  fail: ["M12 2.5a9.5 9.5 0 1 0 0 19a9.5 9.5 0 1 0 0-19", "M8.5 8.5l7 7", "M15.5 8.5l-7 7"],
  warn: ["M12 3L2.5 20h19z", "M12 9.5v5", "M12 17.2v.3"],
  info: ["M12 2.5a9.5 9.5 0 1 0 0 19a9.5 9.5 0 1 0 0-19", "M12 11v6", "M12 7.3v.3"],
  link: ["M9.5 14.5l-2 2a3 3 0 0 1-4.2-4.2l3-3a3 3 0 0 1 4.2 0", "M14.5 9.5l2-2a3 3 0 0 1 4.2 4.2l-3 3a3 3 0 0 1-4.2 0", "M4 4l3 3", "M17 17l3 3"],
  hand: ["M8 12V5.5a1.5 1.5 0 0 1 3 0V11", "M11 10.5V4a1.5 1.5 0 0 1 3 0v7", "M14 10.5V5.5a1.5 1.5 0 0 1 3 0V14a7 7 0 0 1-7 7H9.5a5 5 0 0 1-4.2-2.3L3 15a1.6 1.6 0 0 1 2.6-1.8L8 15.5"],
  clock: ["M12 2.5a9.5 9.5 0 1 0 0 19a9.5 9.5 0 1 0 0-19", "M12 7v5l3.5 2"],
  axis: ["M20 12a8 8 0 1 1-2.4-5.7", "M18.5 2.5v4h-4"],
  fast: ["M13 2L4 14h7l-1 8 9-12h-7z"],
  stop: ["M12 2.5a9.5 9.5 0 1 0 0 19a9.5 9.5 0 1 0 0-19", "M9 9h6v6H9z"],
  battery: ["M3 8h15v8H3z", "M18 10.5h2.5v3H18"],
  ready: ["M12 2.5a9.5 9.5 0 1 0 0 19a9.5 9.5 0 1 0 0-19", "M7.5 12.5l3 3 6-6.5"],
  busy: ["M12 2.5a9.5 9.5 0 1 0 0 19a9.5 9.5 0 1 0 0-19", "M12 7v5h4"],
  offline: ["M12 2.5a9.5 9.5 0 1 0 0 19a9.5 9.5 0 1 0 0-19", "M5.5 5.5l13 13"],
  history: ["M3.5 12a8.5 8.5 0 1 0 2.5-6", "M3 3.5v4h4", "M12 7.5V12l3 2"],
  user: ["M12 12a4 4 0 1 0 0-8a4 4 0 1 0 0 8", "M4 21a8 8 0 0 1 16 0"],
  search: ["M10.5 3.5a7 7 0 1 0 0 14a7 7 0 1 0 0-14", "M15.5 15.5L21 21"],
  back: ["M15 5l-7 7 7 7"],
  save: ["M5 3.5h11l3.5 3.5v13.5H5z", "M8 3.5v5h7v-5", "M8 20v-6h8v6"],
  redo: ["M4 12a8 8 0 1 0 2.4-5.7", "M5.5 2.5v4h4"],
  trash: ["M4 6.5h16", "M9 6.5V4h6v2.5", "M6.5 6.5l1 14h9l1-14"],
  play: ["M7 4.5v15l12-7.5z"],
  bell: ["M6 16.5V11a6 6 0 0 1 12 0v5.5l1.5 2h-15z", "M10 20.5a2 2 0 0 0 4 0"],
  speaker: ["M4 9.5h4l5-4v13l-5-4H4z", "M16.5 9a4 4 0 0 1 0 6", "M19 6.5a7.5 7.5 0 0 1 0 11"],
  upload: ["M6 3.5h8l4 4v13H6z", "M14 3.5v4h4", "M12 17.5v-6", "M9.5 14l2.5-2.5 2.5 2.5"],
  fleet: ["M3.5 20.5h17", "M5 20.5V7l7-3.5 7 3.5v13.5", "M8.5 10h1", "M14.5 10h1", "M8.5 14h1", "M14.5 14h1", "M10.5 20.5v-3h3v3"],
  blink: ["M12 8a4 4 0 1 0 0 8a4 4 0 1 0 0-8", "M12 2v2.5", "M12 19.5V22", "M2 12h2.5", "M19.5 12H22", "M4.9 4.9l1.8 1.8", "M17.3 17.3l1.8 1.8", "M19.1 4.9l-1.8 1.8", "M6.7 17.3l-1.8 1.8"],
};

/** An icon: decorative (aria-hidden) unless given a label. */
export function icon(name, { label, cls } = {}) {
  const el = s("svg", { viewBox: "0 0 24 24", class: ["icon", cls], "aria-hidden": label ? null : "true", role: label ? "img" : null, "aria-label": label || null, focusable: "false" });
  for (const d of ICON_PATHS[name] || ICON_PATHS.info) el.append(s("path", { d }));
  return el;
}

/** A notice box: an icon and a sentence; kind warn, info or error (an error is announced at once). */
export function notice(kind, iconName, text, label = null) {
  return h("div", { class: `notice ${kind}`, role: kind === "error" ? "alert" : "status" }, icon(iconName),
    h("span", null, label ? h("strong", { class: "notice-label" }, label) : null, label ? " " : null, text));
}

// -- the device and its printed axes -----------------------------------------------------------
const AXIS_CLASS = { x: "ax-x", y: "ax-y", z: "ax-z" };

/** The wearable seen from above: a case with the X (right), Y (up) and Z (out of the face) axes printed. */
function deviceFace(x, y, w, hgt) {
  const cx = x + w / 2;
  const cy = y + hgt / 2;
  const L = Math.min(w, hgt) * 0.32;
  return s("g", { class: "device-face" },
    s("rect", { x: x - 10, y: cy - 18, width: 12, height: 36, rx: 3, class: "strap" }),
    s("rect", { x: x + w - 2, y: cy - 18, width: 12, height: 36, rx: 3, class: "strap" }),
    s("rect", { x, y, width: w, height: hgt, rx: 18, class: "case" }),
    s("circle", { cx: x + w - 16, cy: y + 16, r: 4, class: "led" }),
    // X: to the right
    s("line", { x1: cx, y1: cy, x2: cx + L, y2: cy, class: "axis-line ax-x" }),
    s("path", { d: `M${cx + L + 9} ${cy} l-12 -7 v14 z`, class: "axis-head ax-x" }),
    s("text", { x: cx + L - 8, y: cy + 30, class: "axis-label ax-x" }, "X"),
    // Y: up
    s("line", { x1: cx, y1: cy, x2: cx, y2: cy - L, class: "axis-line ax-y" }),
    s("path", { d: `M${cx} ${cy - L - 9} l-7 12 h14 z`, class: "axis-head ax-y" }),
    s("text", { x: cx - 30, y: cy - L + 12, class: "axis-label ax-y" }, "Y"),
    // Z: out of the face
    s("circle", { cx, cy, r: 9, class: "axis-ring ax-z" }),
    s("circle", { cx, cy, r: 3.2, class: "axis-dot ax-z" }),
    s("text", { x: cx - 30, y: cy + 28, class: "axis-label ax-z" }, "Z"),
  );
}

/** Step 1's picture: the device lying flat on the table, pushed against the block. */
export function placePicture() {
  return s("svg", { viewBox: "0 0 340 250", class: "place-picture", role: "img", "aria-label": "The device lying flat on the table, face up, pushed against the block; X points right along the block, Y points away from it, Z points up." },
    s("rect", { x: 6, y: 6, width: 328, height: 238, rx: 16, class: "table" }),
    s("rect", { x: 30, y: 196, width: 280, height: 30, rx: 5, class: "block" }),
    s("text", { x: 170, y: 217, class: "block-label" }, "block"),
    deviceFace(95, 54, 150, 142),
  );
}

/** The device alone, for the turn animation (front and back faces). */
function deviceCard() {
  const front = s("svg", { viewBox: "0 0 200 180", class: "card-face front", "aria-hidden": "true" }, deviceFace(25, 19, 150, 142));
  const back = s("svg", { viewBox: "0 0 200 180", class: "card-face back", "aria-hidden": "true" },
    s("rect", { x: 25, y: 19, width: 150, height: 142, rx: 18, class: "case-back" }),
    s("text", { x: 100, y: 96, class: "back-label" }, "back"));
  return h("div", { class: "card" }, front, back);
}

/** The required turn, animated: the device spins a full turn about the axis, which is drawn through it. */
export function turnAnimation(axis) {
  const label = AXIS_LABEL[axis];
  const guide = s("svg", { viewBox: "0 0 300 300", class: "axis-guide", "aria-hidden": "true" });
  if (axis === "x") {
    guide.append(
      s("line", { x1: 8, y1: 150, x2: 292, y2: 150, class: `guide-line ${AXIS_CLASS.x}` }),
      s("ellipse", { cx: 262, cy: 150, rx: 14, ry: 44, class: `guide-turn ${AXIS_CLASS.x}` }),
      s("path", { d: "M262 106 l-9 -6 v12 z", class: `guide-head ${AXIS_CLASS.x}` }),
    );
  } else if (axis === "y") {
    guide.append(
      s("line", { x1: 150, y1: 8, x2: 150, y2: 292, class: `guide-line ${AXIS_CLASS.y}` }),
      s("ellipse", { cx: 150, cy: 30, rx: 44, ry: 14, class: `guide-turn ${AXIS_CLASS.y}` }),
      s("path", { d: "M194 30 l6 -9 h-12 z", class: `guide-head ${AXIS_CLASS.y}` }),
    );
  } else {
    guide.append(
      s("circle", { cx: 150, cy: 150, r: 138, class: `guide-turn ${AXIS_CLASS.z}` }),
      s("path", { d: "M150 12 l-12 -7 v14 z", class: `guide-head ${AXIS_CLASS.z}` }),
    );
  }
  return h("div", { class: "turn-wrap" },
    h("div", { class: `turn-anim turn-${axis}`, role: "img", "aria-label": `Animation: the device turns one full turn about its ${label} axis and comes back to its place.` },
      guide, h("div", { class: "spin" }, deviceCard())),
    h("p", { class: `axis-caption ${AXIS_CLASS[axis]}` }, `${label} axis`));
}

// -- live feedback -----------------------------------------------------------------------------
const RING_R = 88;
const RING_C = 2 * Math.PI * RING_R;

/** The phases of a turn state in which the device rests (the ring counts its rest); in the others the gauge follows
 * the turn. */
export const REST_PHASES = ["pause", "settle", "checking"];

/** The stillness ring; update(fraction, moving, seconds left) as progress events arrive. ``thing``: what rests. */
export function stillRing(thing = "the device") {
  const arc = s("circle", { cx: 100, cy: 100, r: RING_R, class: "ring-fill", "stroke-dasharray": RING_C.toFixed(2), "stroke-dashoffset": RING_C.toFixed(2), transform: "rotate(-90 100 100)" });
  const big = s("text", { x: 100, y: 104, class: "ring-text" }, "");
  const small = s("text", { x: 100, y: 134, class: "ring-sub" }, "");
  const svg = s("svg", { viewBox: "0 0 200 200", class: "ring", "aria-hidden": "true" },
    s("circle", { cx: 100, cy: 100, r: RING_R, class: "ring-track" }), arc, big, small);
  const el = h("div", { class: "ring-wrap", role: "progressbar", "aria-label": `Time ${thing} has been still`, "aria-valuemin": "0", "aria-valuemax": "100", "aria-valuenow": "0" }, svg);
  el.update = (fraction, moving, left) => {
    const f = Math.max(0, Math.min(1, fraction || 0));
    arc.setAttribute("stroke-dashoffset", (RING_C * (1 - f)).toFixed(2));
    el.classList.toggle("moving", Boolean(moving));
    el.classList.toggle("full", f >= 1);
    el.setAttribute("aria-valuenow", String(Math.round(f * 100)));
    big.textContent = moving ? "moving" : f >= 1 ? "✓" : `${Math.max(0, left).toFixed(1)} s`;
    small.textContent = moving ? "hold it still" : f >= 1 ? "still" : "to go";
  };
  return el;
}

const GAUGE_R = 84;

function polar(deg, r = GAUGE_R) {
  const a = ((deg - 90) * Math.PI) / 180;
  return [100 + r * Math.cos(a), 100 + r * Math.sin(a)];
}

/** The live angle gauge of the current turn; update(angle, target) with the signed live angle and its target.
 * With a target (the device's accepted calibration makes the angle true degrees) the arc fills towards 360°
 * and the degrees are shown. Without one the raw angle can be 20 % off a full turn, so no number and no
 * end mark are shown: only a marker that goes round as the device turns. ``thing``: what is turned. */
export function angleGauge(axis, thing = "the device") {
  const arc = s("path", { class: `gauge-fill ${AXIS_CLASS[axis]}`, d: "" });
  const dot = s("circle", { r: 9, class: `gauge-dot ${AXIS_CLASS[axis]}`, cx: 100, cy: 100 - GAUGE_R });
  const text = s("text", { x: 100, y: 108, class: "gauge-text" }, "0°");
  const sub = s("text", { x: 100, y: 136, class: "gauge-sub" }, `about ${AXIS_LABEL[axis]}`);
  const goal = s("path", { class: "gauge-goal", d: `M100 ${100 - GAUGE_R - 16} v32` });
  const svg = s("svg", { viewBox: "0 0 200 200", class: "gauge", "aria-hidden": "true" },
    s("circle", { cx: 100, cy: 100, r: GAUGE_R, class: "gauge-track" }),
    ...[0, 90, 180, 270].map((d) => {
      const [x1, y1] = polar(d, GAUGE_R - 14);
      const [x2, y2] = polar(d, GAUGE_R - 4);
      return s("line", { x1, y1, x2, y2, class: "gauge-tick" });
    }),
    arc, goal, dot, text, sub);
  const el = h("div", { class: "gauge-wrap", role: "meter", "aria-label": `Measured turn about ${AXIS_LABEL[axis]}`, "aria-valuemin": "0", "aria-valuemax": "360", "aria-valuenow": "0" }, svg);
  el.update = (angle, target, stopped = false) => {
    const a = Math.abs(Number(angle) || 0);
    const targeted = Boolean(target);
    el.classList.toggle("no-target", !targeted);
    el.dataset.target = targeted ? String(target) : "";
    if (!targeted) {
      // a marker that turns with the device, and words instead of a number it cannot know
      const [x, y] = polar(a % 360);
      arc.setAttribute("d", "");
      dot.setAttribute("cx", x.toFixed(2));
      dot.setAttribute("cy", y.toFixed(2));
      // stopped: the motion has stopped and the device is being put down (the stillness ring follows once it rests)
      text.textContent = stopped ? "stopped" : a < 5 ? "ready" : "turning";
      sub.textContent = stopped ? "hold it still" : "back to the block";
      el.setAttribute("aria-valuenow", String(Math.min(360, Math.round(a)))); // a meter needs a value; its text says more
      el.setAttribute("aria-valuetext", stopped ? "stopped; hold it still" : a < 5 ? "not turning yet"
        : `turning; no angle target: stop when ${thing} is back against the block`);
      return;
    }
    const shown = Math.min(a, 359.9);
    const [x, y] = polar(shown);
    const large = shown > 180 ? 1 : 0;
    arc.setAttribute("d", shown < 0.5 ? "" : `M100 ${100 - GAUGE_R} A${GAUGE_R} ${GAUGE_R} 0 ${large} 1 ${x.toFixed(2)} ${y.toFixed(2)}`);
    dot.setAttribute("cx", x.toFixed(2));
    dot.setAttribute("cy", y.toFixed(2));
    text.textContent = `${Math.round(a)}°`;
    sub.textContent = `of ${Math.round(target)}° about ${AXIS_LABEL[axis]}`;
    el.setAttribute("aria-valuenow", String(Math.round(Math.min(a, 360))));
    el.removeAttribute("aria-valuetext");
  };
  return el;
}

/** The stillness ring as a snapshot (a session's, or a kit's) has it: its rest's progress, or moving. */
export function showRest(ring, s) {
  const p = s.progress || { fraction: 0, still_s: 0, target_s: 0 };
  const moving = Boolean(s.live && s.live.moving);
  ring.update(moving ? 0 : p.fraction, moving, (p.target_s || 0) - (p.still_s || 0));
}

/** The angle gauge as a snapshot has it: the live angle while turning or being put down (placing), else none yet. */
export function showTurn(gauge, s) {
  gauge.update(["turning", "placing"].includes(s.phase) && s.live ? s.live.turn_angle_deg : 0, s.live && s.live.target_deg,
    s.phase === "placing");
}

/** The three turn tiles: each to do, active (now) or done. */
export function turnTiles() {
  const tiles = {};
  const list = h("ol", { class: "tiles", "aria-label": "The three turns" });
  for (const a of ["x", "y", "z"]) {
    const glyph = h("span", { class: "tile-icon" });
    const state = h("span", { class: "tile-state" });
    const li = h("li", { class: ["tile", AXIS_CLASS[a]] }, glyph, h("span", { class: "tile-axis" }, `Turn ${AXIS_LABEL[a]}`), state);
    tiles[a] = { li, glyph, state };
    list.append(li);
  }
  // ``again``: the active turn was shown done before and is asked again (the result found it was not a full turn):
  // said as that, never as a plain "now" that takes back what she saw done without a word
  list.update = (doneAxes, activeAxis, again = false) => {
    for (const [a, t] of Object.entries(tiles)) {
      const st = doneAxes.includes(a) ? "done" : a === activeAxis ? (again ? "again" : "active") : "todo";
      if (t.li.dataset.state === st) continue;
      t.li.dataset.state = st;
      t.glyph.replaceChildren(icon({ done: "check", active: "axis", again: "redo" }[st] || "clock"));
      t.state.textContent = { done: "done", active: "now", again: "again" }[st] || "to do";
      if (st === "active" || st === "again") t.li.setAttribute("aria-current", "step");
      else t.li.removeAttribute("aria-current");
    }
  };
  return list;
}

/** The kit's tray seen from above, against the block: its wearables in their slots, and the axis the whole tray is to
 * be turned about (none: it rests). */
export function trayPicture(names, axis) {
  const n = Math.max(names.length, 1);
  const cols = Math.min(n, 3);
  const rows = Math.ceil(n / cols);
  const w = 300, tray = 28 + rows * 70, hgt = tray + 50;
  const say = axis
    ? `The tray with its ${n} wearables, to be turned one full turn about its ${AXIS_LABEL[axis]} axis, then put back against the block.`
    : `The tray with its ${n} wearables, lying flat against the block: keep it still.`;
  const slot = 240 / cols;
  const slots = names.map((name, i) => {
    const x = 30 + (i % cols) * slot, y = 24 + Math.floor(i / cols) * 70;
    return s("g", null,
      s("rect", { x, y, width: slot - 16, height: 54, rx: 8, class: "case" }),
      s("text", { x: x + (slot - 16) / 2, y: y + 32, class: "slot-label" }, name));
  });
  const mid = 10 + tray / 2;
  // the axis is drawn under the wearables, so that their names stay readable, and its letter over them, clear of them
  const [guide, letter] = axis === "x" ? [s("line", { x1: 2, y1: mid, x2: w - 22, y2: mid, class: `guide-line ${AXIS_CLASS.x}` }),
    s("text", { x: w - 14, y: mid + 6, class: `axis-letter ${AXIS_CLASS.x}` }, "X")]
    : axis === "y" ? [s("line", { x1: w / 2, y1: tray + 18, x2: w / 2, y2: 20, class: `guide-line ${AXIS_CLASS.y}` }),
      s("text", { x: w / 2 + 8, y: 18, class: `axis-letter ${AXIS_CLASS.y}` }, "Y")]
      : axis === "z" ? [s("circle", { cx: w / 2, cy: mid, r: tray / 2 - 4, class: `guide-turn ${AXIS_CLASS.z}` }),
        s("text", { x: w / 2 + 8, y: 21, class: `axis-letter ${AXIS_CLASS.z}` }, "Z")] : [null, null];
  return s("svg", { viewBox: `0 0 ${w} ${hgt}`, class: "tray-picture", role: "img", "aria-label": say, "data-axis": axis || "" },
    s("rect", { x: 14, y: 10, width: w - 28, height: tray, rx: 14, class: "tray" }),
    s("rect", { x: 14, y: tray + 14, width: w - 28, height: 26, rx: 5, class: "block" }),
    s("text", { x: w / 2, y: tray + 32, class: "block-label" }, "block"),
    guide, ...slots, letter);
}
