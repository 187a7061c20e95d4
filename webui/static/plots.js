// Line plots as inline SVG: the before/after traces of a calibration and the parameters over time.

import { fmtDate, h, s } from "./dom.js";

const W = 640;
const H = 250;
const M = { l: 62, r: 16, t: 14, b: 44 };

/** About `count` round tick values covering [lo, hi]. */
export function niceTicks(lo, hi, count = 5) {
  if (!(hi > lo)) {
    const pad = Math.abs(lo) > 0 ? Math.abs(lo) * 0.05 : 1;
    lo -= pad;
    hi += pad;
  }
  const raw = (hi - lo) / Math.max(1, count);
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((st) => st >= raw) || raw;
  const start = Math.floor(lo / step) * step;
  const ticks = [];
  for (let v = start; v <= hi + step * 0.5 && ticks.length < 50; v += step) ticks.push(Number(v.toPrecision(12)));
  return ticks;
}

function extent(arrays) {
  let lo = Infinity;
  let hi = -Infinity;
  for (const a of arrays) for (const v of a) if (v !== null && Number.isFinite(v)) {
    if (v < lo) lo = v;
    if (v > hi) hi = v;
  }
  return lo <= hi ? [lo, hi] : [0, 1];
}

function tickText(v, ticks) {
  const step = ticks.length > 1 ? Math.abs(ticks[1] - ticks[0]) : 1;
  const d = step >= 1 ? 0 : Math.min(6, Math.ceil(-Math.log10(step)));
  return v.toFixed(d);
}

function frame(xTicks, yTicks, sx, sy, xFmt, xLabel, yLabel, top = M.t, yFmt = tickText) {
  const g = s("g", { class: "axes" });
  for (const v of yTicks) {
    const y = sy(v);
    g.append(s("line", { x1: M.l, x2: W - M.r, y1: y, y2: y, class: "grid" }),
      s("text", { x: M.l - 8, y: y + 4, class: "tick y" }, yFmt(v, yTicks)));
  }
  for (const v of xTicks) {
    const x = sx(v);
    const lab = xFmt(v, xTicks);
    const text = Array.isArray(lab) ? [s("tspan", { x }, lab[0]), s("tspan", { x, dy: 16 }, lab[1])] : lab;
    g.append(s("line", { x1: x, x2: x, y1: H - M.b, y2: H - M.b + 5, class: "tickmark" }),
      s("text", { x, y: H - M.b + 19, class: "tick x" }, text));
  }
  g.append(
    s("line", { x1: M.l, x2: W - M.r, y1: H - M.b, y2: H - M.b, class: "axis" }),
    s("line", { x1: M.l, x2: M.l, y1: top, y2: H - M.b, class: "axis" }),
    s("text", { x: (M.l + W - M.r) / 2, y: H - 6, class: "axis-title" }, xLabel),
    s("text", { x: 14, y: (top + H - M.b) / 2, class: "axis-title", transform: `rotate(-90 14 ${(top + H - M.b) / 2})` }, yLabel),
  );
  return g;
}

function legend(series) {
  return h("ul", { class: "legend" }, series.filter((se) => se.label).map((se) => h("li", null,
    s("svg", { viewBox: "0 0 36 12", class: "legend-key", "aria-hidden": "true" },
      se.points ? s("g", { class: `series ${se.cls}` }, marker(se.marker, 18, 6, 4)) : s("line", { x1: 2, x2: 34, y1: 6, y2: 6, class: `series ${se.cls}` })),
    se.label)));
}

function marker(kind, x, y, r) {
  if (kind === "square") return s("rect", { x: x - r, y: y - r, width: 2 * r, height: 2 * r, class: "marker" });
  if (kind === "triangle") return s("path", { d: `M${x} ${y - r * 1.2} L${x + r * 1.1} ${y + r * 0.8} L${x - r * 1.1} ${y + r * 0.8} Z`, class: "marker" });
  return s("circle", { cx: x, cy: y, r, class: "marker" });
}

/**
 * A line chart of series sharing an x axis.
 * opts: {title, caption, xLabel, yLabel, series: [{x, y, label, cls}], bands: [{from, to, label}], yZero, xFmt, yFmt,
 * yTicks (the y ticks to draw, in place of round ones)}
 */
export function lineChart(opts) {
  const series = opts.series;
  let [x0, x1] = extent(series.map((se) => se.x));
  let [y0, y1] = extent(series.map((se) => se.y));
  if (opts.yZero) y0 = Math.min(0, y0);
  const yTicks = opts.yTicks || niceTicks(y0, y1, 5);
  y0 = Math.min(y0, yTicks[0]);
  y1 = Math.max(y1, yTicks[yTicks.length - 1]);
  const xTicks = (opts.xTicks || niceTicks(x0, x1, 8)).filter((v) => v >= x0 - 1e-9 && v <= x1 + 1e-9);
  if (x1 === x0) x1 = x0 + 1;
  if (y1 === y0) y1 = y0 + 1;
  // the bands' labels get a strip of their own above the plot, so no curve runs through them
  const top = opts.bands && opts.bands.length ? M.t + 20 : M.t;
  const sx = (v) => M.l + ((v - x0) / (x1 - x0)) * (W - M.l - M.r);
  const sy = (v) => H - M.b - ((v - y0) / (y1 - y0)) * (H - top - M.b);
  const svg = s("svg", { viewBox: `0 0 ${W} ${H}`, class: "chart", role: "img", "aria-label": opts.caption || opts.title });
  for (const b of opts.bands || []) {
    svg.append(s("rect", { x: sx(b.from), y: M.t, width: Math.max(1, sx(b.to) - sx(b.from)), height: H - M.t - M.b, class: "band" }),
      s("text", { x: (sx(b.from) + sx(b.to)) / 2, y: M.t + 13, class: "band-label" }, b.label));
  }
  svg.append(frame(xTicks, yTicks, sx, sy, opts.xFmt || ((v, t) => tickText(v, t)), opts.xLabel, opts.yLabel, top,
    opts.yFmt || tickText));
  for (const se of series) {
    let d = "";
    let pen = false;
    for (let i = 0; i < se.x.length; i++) {
      const v = se.y[i];
      if (v === null || !Number.isFinite(v)) {
        pen = false;
        continue;
      }
      d += `${pen ? "L" : "M"}${sx(se.x[i]).toFixed(1)} ${sy(v).toFixed(1)}`;
      pen = true;
    }
    svg.append(s("path", { d, class: `series ${se.cls}` }));
  }
  return h("figure", { class: "plot" },
    h("figcaption", null, h("strong", null, opts.title), opts.caption ? ` — ${opts.caption}` : ""),
    svg, legend(series));
}

const sameDay = (a, b) => a.getFullYear() === b.getFullYear() && a.getMonth() === b.getMonth() && a.getDate() === b.getDate();
const hhmm = new Intl.DateTimeFormat(undefined, { hour: "2-digit", minute: "2-digit" });

/**
 * Values of successive calibrations, evenly spaced and labelled with their dates, with ±1σ error bars.
 * opts: {title, caption, yLabel, when: [Date] (oldest first), series: [{y, err, label, cls, marker}]}
 */
export function historyChart(opts) {
  const { series, when } = opts;
  const n = when.length;
  const ys = series.flatMap((se) => se.y.map((v, i) => [v - (se.err?.[i] || 0), v + (se.err?.[i] || 0)]).flat());
  let [y0, y1] = extent([ys]);
  const yTicks = opts.yTicks || niceTicks(y0, y1, 5);
  y0 = Math.min(y0, yTicks[0]);
  y1 = Math.max(y1, yTicks[yTicks.length - 1]);
  if (y1 === y0) y1 = y0 + 1;
  const x0 = -0.5;
  const x1 = n - 0.5;
  const sx = (i) => M.l + ((i - x0) / (x1 - x0)) * (W - M.l - M.r);
  const sy = (v) => H - M.b - ((v - y0) / (y1 - y0)) * (H - M.t - M.b);
  const every = Math.max(1, Math.ceil(n / 6));
  const xTicks = [...Array(n).keys()].filter((i) => (n - 1 - i) % every === 0);
  // a calibration's date, and its time when a neighbour shares the date
  const label = (i) => {
    const d = when[i];
    const twin = (i > 0 && sameDay(when[i - 1], d)) || (i < n - 1 && sameDay(when[i + 1], d));
    return twin ? [fmtDate(d.toISOString()), hhmm.format(d)] : fmtDate(d.toISOString());
  };
  const svg = s("svg", { viewBox: `0 0 ${W} ${H}`, class: "chart", role: "img", "aria-label": opts.caption || opts.title });
  svg.append(frame(xTicks, yTicks, sx, sy, label, "", opts.yLabel));
  for (const se of series) {
    const g = s("g", { class: `series ${se.cls}` });
    const pts = se.y.map((v, i) => [sx(i), sy(v)]);
    if (pts.length > 1) g.append(s("path", { d: pts.map(([x, y], i) => `${i ? "L" : "M"}${x.toFixed(1)} ${y.toFixed(1)}`).join(""), class: "connect" }));
    se.y.forEach((v, i) => {
      const e = se.err?.[i];
      if (e) g.append(s("line", { x1: sx(i), x2: sx(i), y1: sy(v - e), y2: sy(v + e), class: "errbar" }));
      g.append(marker(se.marker, pts[i][0], pts[i][1], 5));
    });
    svg.append(g);
  }
  return h("figure", { class: "plot" },
    h("figcaption", null, h("strong", null, opts.title), opts.caption ? ` — ${opts.caption}` : ""),
    svg, legend(series.map((se) => ({ ...se, points: true }))));
}

/**
 * A parameter against the sensor's temperature: each calibration made at a known temperature as a point, and the
 * device's model (the line its watches measured) over the temperatures they saw.
 * opts: {title, caption, yLabel, series: [{label, cls, marker, points: [[T, v]], line: [[T, v], [T, v]] | null}]}
 */
export function temperatureChart(opts) {
  const xs = opts.series.flatMap((se) => [...se.points, ...(se.line || [])].map(([x]) => x));
  const ys = opts.series.flatMap((se) => [...se.points, ...(se.line || [])].map(([, y]) => y));
  let [x0, x1] = extent([xs]);
  let [y0, y1] = extent([ys]);
  if (x1 - x0 < 1) [x0, x1] = [x0 - 1, x1 + 1];
  if (y1 === y0) [y0, y1] = [y0 - 0.001, y1 + 0.001];
  const xTicks = niceTicks(x0, x1, 6);
  const yTicks = opts.yTicks || niceTicks(y0, y1, 5);
  [x0, x1] = [Math.min(x0, xTicks[0]), Math.max(x1, xTicks[xTicks.length - 1])];
  [y0, y1] = [Math.min(y0, yTicks[0]), Math.max(y1, yTicks[yTicks.length - 1])];
  const sx = (v) => M.l + ((v - x0) / (x1 - x0)) * (W - M.l - M.r);
  const sy = (v) => H - M.b - ((v - y0) / (y1 - y0)) * (H - M.t - M.b);
  const svg = s("svg", { viewBox: `0 0 ${W} ${H}`, class: "chart", role: "img", "aria-label": opts.caption || opts.title });
  svg.append(frame(xTicks, yTicks, sx, sy, (v) => tickText(v, xTicks), "sensor temperature, °C", opts.yLabel));
  for (const se of opts.series) {
    const g = s("g", { class: `series ${se.cls}` });
    if (se.line) g.append(s("path", { d: se.line.map(([x, y], i) => `${i ? "L" : "M"}${sx(x).toFixed(1)} ${sy(y).toFixed(1)}`).join(""), class: "model" }));
    for (const [x, y] of se.points) g.append(marker(se.marker, sx(x), sy(y), 5));
    svg.append(g);
  }
  return h("figure", { class: "plot temperature" },
    h("figcaption", null, h("strong", null, opts.title), opts.caption ? ` — ${opts.caption}` : ""),
    svg, legend(opts.series.map((se) => ({ ...se, points: se.points.length > 0 }))));
}

/** The two figures of a calibration: rate magnitude and orientation, before and after. */
export function calibrationPlots(tr) {
  const bands = (tr.turns || []).map((t) => ({ from: t.start_s, to: t.end_s, label: `turn ${String(t.axis).toUpperCase()}` }));
  const before = { cls: "before", label: "before calibration (raw readings)" };
  const after = { cls: "after", label: "after calibration" };
  return [
    lineChart({
      title: "Rotation speed",
      caption: "the size of the measured rate; at rest it should be 0 after calibration",
      xLabel: "time (s)", yLabel: "°/s", yZero: true, bands,
      series: [{ ...before, x: tr.t, y: tr.rate_before }, { ...after, x: tr.t, y: tr.rate_after }],
    }),
    lineChart({
      title: "Estimated orientation",
      caption: "angle from the starting position, integrated from the gyroscope; after a full turn it should come back to 0",
      xLabel: "time (s)", yLabel: "angle (°)", yZero: true, bands,
      series: [{ ...before, x: tr.t, y: tr.pose_error_before }, { ...after, x: tr.t, y: tr.pose_error_after }],
    }),
  ];
}

/** Roll, pitch and yaw a recording implies before and after its calibration, and the angle between the two. */
export function orientationPlots(o) {
  const before = { cls: "before", label: "raw readings" };
  const after = { cls: "after", label: "calibrated" };
  const angle = (name, caption) => lineChart({
    title: name[0].toUpperCase() + name.slice(1), caption, xLabel: "time (s)", yLabel: "°",
    series: [{ ...before, x: o.t, y: o.before[name] }, { ...after, x: o.t, y: o.after[name] }],
  });
  return [
    angle("yaw", "the heading: only the gyroscope tells it, so a calibration shows here most"),
    angle("pitch", "held to gravity by the accelerometer when the recording has one"),
    angle("roll", "held to gravity by the accelerometer when the recording has one"),
    lineChart({
      title: "Difference", caption: "the angle between the orientation from raw and from calibrated readings",
      xLabel: "time (s)", yLabel: "°", yZero: true, series: [{ cls: "after", label: "difference", x: o.t, y: o.difference_deg }],
    }),
  ];
}
