// Noise from a long rest (docs/method.md, "Noise from a long rest"): a recording of the device lying still, uploaded,
// gives each axis's Allan deviation with its 95 % band and the noise density, bias instability and random walk read
// from it, each with its interval (or a bound where the curve does not show it), and Kalibr's imu.yaml.

import { fill, h, num } from "./dom.js";
import { icon } from "./figures.js";
import { problemLine } from "./messages.js";
import { lineChart } from "./plots.js";

const AXIS_CLS = { x: "ax-x", y: "ax-y", z: "ax-z" };
// what each parameter is shown as: a datasheet's unit and the factor from the report's
const SHOWN = {
  gyro: { noise_density: [60, "°/√h"], bias_instability: [3600, "°/h"], random_walk: [3600 * 60, "°/h/√h"] },
  accel: { noise_density: [1e6, "µg/√Hz"], bias_instability: [1e6, "µg"], random_walk: [1e6, "µg/√s"] },
};

/** A reading in a few words: "0.60 °/√h (0.596–0.601)" when seen, "< 113 °/h/√h" when only bounded. */
export function readingText(r, sensor, which) {
  const [f, unit] = SHOWN[sensor][which];
  const sig = (v) => Number((v * f).toPrecision(3));
  if (!r.seen) return `< ${sig(r.upper95)} ${unit}`;
  return `${sig(r.value)} ${unit} (${sig(r.ci95[0])}–${sig(r.ci95[1])})`;
}

function table(sensor, axes) {
  const head = sensor === "gyro" ? ["Axis", "Noise density (angle random walk)", "Bias instability", "Rate random walk"]
    : ["Axis", "Noise density (velocity random walk)", "Bias instability", "Acceleration random walk"];
  const name = sensor === "gyro" ? "Gyroscope noise" : "Accelerometer noise";
  // a region the keyboard can scroll, as a phone's narrow screen may need
  return h("div", { class: "table-wrap", tabindex: "0", role: "region", "aria-label": name }, h("table", { class: `history noise-table ${sensor}` },
    h("caption", null, sensor === "gyro" ? "Gyroscope" : "Accelerometer"),
    h("thead", null, h("tr", null, head.map((c) => h("th", { scope: "col" }, c)))),
    h("tbody", null, axes.map((a) => h("tr", { "data-axis": a.axis },
      h("th", { scope: "row" }, a.axis.toUpperCase()),
      ["noise_density", "bias_instability", "random_walk"].map((w) => h("td", { "data-seen": String(a[w].seen) },
        readingText(a[w], sensor, w), h("span", { class: "muted tau" }, ` τ ${Number(a[w].tau_s.toPrecision(3))} s`))))))));
}

const log10 = (v) => (v > 0 ? Math.log10(v) : null);
const pow10 = (v) => {
  const x = 10 ** v;
  return x >= 1e5 || x < 0.001 ? x.toExponential(0) : String(Number(x.toPrecision(2)));
};
const decades = (lo, hi) => {
  const out = [];
  for (let e = Math.floor(lo); e <= Math.ceil(hi); e++) out.push(e);
  return out;
};

/** The Allan deviation of each axis on log axes: measured (solid), its 95 % band (dotted) and the fit (dashed). */
export function allanChart(axes, sensor) {
  const [f, unit] = sensor === "gyro" ? [3600, "°/h"] : [1e6, "µg"];
  const series = [];
  for (const a of axes) {
    const x = a.curve.tau_s.map(log10);
    const scaled = (arr) => arr.map((v) => log10(v * f));
    const cls = AXIS_CLS[a.axis] || "ax-x";
    series.push({ x, y: scaled(a.curve.adev), label: `${a.axis.toUpperCase()} measured`, cls: `${cls} measured` },
      { x, y: scaled(a.curve.lo95), label: `${a.axis.toUpperCase()} 95 % band`, cls: `${cls} band-edge` },
      { x, y: scaled(a.curve.hi95), label: "", cls: `${cls} band-edge` },
      { x, y: scaled(a.curve.fit_adev), label: `${a.axis.toUpperCase()} fitted`, cls: `${cls} fitted` });
  }
  const ys = series.flatMap((se) => se.y).filter((v) => v !== null);
  const xs = series.flatMap((se) => se.x).filter((v) => v !== null);
  return lineChart({
    title: `${sensor === "gyro" ? "Gyroscope" : "Accelerometer"} Allan deviation`,
    caption: "log scales; the noise density is read where the curve falls as τ^-½, the bias instability at its floor, "
      + "the random walk where it rises as τ^½",
    xLabel: "averaging time τ (s)", yLabel: `Allan deviation (${unit})`,
    series,
    xTicks: decades(Math.min(...xs), Math.max(...xs)), yTicks: decades(Math.min(...ys), Math.max(...ys)),
    xFmt: (v) => pow10(v), yFmt: (v) => pow10(v),
  });
}

function result(out) {
  return h("div", { class: "noise-result" },
    h("p", { class: "outcome pass" }, icon("check"), h("span", null,
      `${out.source || "The rest"}: ${num(out.duration_s, 0)} s at ${Number(out.sample_rate_hz.toPrecision(6))} Hz. `
      + "Each figure with its 95 % interval; “<” where the curve does not show the term (its 95 % upper bound).")),
    out.lost_samples ? h("p", { class: "form-error" }, icon("warn"), h("span", null, `${out.lost_samples} samples are missing `
      + "from the recording: the curve takes the others as evenly spaced, which bends it near the gaps.")) : null,
    table("gyro", out.gyro), allanChart(out.gyro, "gyro"),
    out.accel ? [table("accel", out.accel), allanChart(out.accel, "accel")] : h("p", { class: "muted" }, "No accelerometer columns: the gyroscope only."),
    out.kalibr_yaml ? h("p", null, h("a", { class: "button", id: "kalibr-download", download: "imu.yaml",
      href: URL.createObjectURL(new Blob([out.kalibr_yaml], { type: "application/yaml" })) }, icon("upload"), "Kalibr imu.yaml")) : null);
}

export function noiseView(ctx) {
  ctx.title("Noise from a rest");
  const file = h("input", { id: "noise-file", type: "file", accept: ".csv,.txt,text/csv,text/plain", required: true });
  const fs = h("input", { id: "noise-fs", type: "number", min: "0", step: "any", placeholder: "from the time column" });
  const status = h("p", { class: "scan-note", role: "status", "aria-live": "polite" });
  const out = h("div", { class: "noise-out" });
  const send = h("button", { class: "button primary", type: "submit" }, icon("check"), "Analyse");
  const form = h("form", { class: "upload-form", novalidate: true },
    h("div", { class: "field" }, h("label", { for: "noise-file" }, "Recording of the device lying still (CSV)"), file,
      h("p", { class: "muted" }, "An hour shows the random walk; a few minutes the noise density. Native or imucal layout.")),
    h("div", { class: "field" }, h("label", { for: "noise-fs" }, "Sample rate (Hz)"), fs,
      h("p", { class: "muted" }, "Only for a file without a time column.")),
    status, send);
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    if (!file.files.length) {
      status.textContent = "Choose the recording's CSV file.";
      file.focus();
      return;
    }
    send.disabled = true;
    fill(out);
    status.textContent = "Reading the Allan deviation of each axis…";
    try {
      const query = { name: file.files[0].name };
      if (fs.value) query.fs = fs.value;
      const rep = await ctx.api.request("POST", "/noise", { csv: await file.files[0].text(), query });
      status.textContent = "";
      fill(out, result(rep));
    } catch (err) {
      if (err.status !== 401) status.textContent = problemLine(err);
    } finally {
      send.disabled = false;
    }
  });
  fill(ctx.main, h("section", { class: "panel", "aria-labelledby": "noise-title" },
    h("div", { class: "panel-head" },
      h("div", null, h("h1", { id: "noise-title" }, "Noise from a rest"),
        h("p", { class: "lead" }, "The sensor's noise density, bias instability and random walk, from a recording of it lying still."))),
    form, out));
  ctx.focusMain();
  return null;
}
