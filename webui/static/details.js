// The engineer's details behind a result: values with their uncertainties, every tolerance check, the turns,
// the facts of the recording, the before/after plots and the model check.

import { AXES, AXIS_LABEL, fill, h, num, sig } from "./dom.js";
import { icon, notice } from "./figures.js";
import { modelCheckPanel } from "./modelcheck.js";
import { calibrationPlots } from "./plots.js";

export function paramTable(k, b, unc) {
  const ku = (unc && unc.k) || [];
  const bu = (unc && unc.b) || [];
  return h("table", { class: "params" },
    h("caption", null, "Calibration g = K·m + b"),
    h("thead", null, h("tr", null, h("th", { scope: "col" }, "Axis"), h("th", { scope: "col" }, "Scale factor k"), h("th", { scope: "col" }, "Bias b (°/s)"))),
    h("tbody", null, AXES.map((a, i) => h("tr", null,
      h("th", { scope: "row" }, AXIS_LABEL[a]),
      k[i] == null ? h("td", null, "not determined") : h("td", null, num(k[i], 5), ku[i] != null ? h("span", { class: "pm" }, ` ± ${sig(ku[i])}`) : null),
      b[i] == null ? h("td", null, "not determined") : h("td", null, num(b[i], 3), bu[i] != null ? h("span", { class: "pm" }, ` ± ${sig(bu[i])}`) : null)))));
}

// What the multi-position fit found about the gyro's sensitivity to acceleration, and the fit without it.
function gSensitivityText(test, G) {
  if (!test) return null;
  if (!test.fitted) return `not modelled: ${test.reason}`;
  const largest = G ? Math.max(...G.flat().map(Math.abs)) : null;
  const before = test.without && test.without.gravity_residual_rms_deg != null
    ? `; without it the gravity residuals were ${num(test.without.gravity_residual_rms_deg, 2)}° rms` : "";
  return `found and modelled (${test.reason})${largest != null ? `, up to ${num(largest, 3)} (°/s)/g` : ""}${before}`;
}

/** The turns of a result: from the estimator's rows (raw and calibrated angle), with the live session's record
 * of each (rest before it) where there is one. */
function turnRows(liveTurns, res) {
  const rows = ((res.residuals && res.residuals.turns) || []).filter((r) => r.axis && r.raw_angle_deg != null);
  if (rows.length) {
    return rows.map((r) => ({ axis: r.axis, raw: Math.abs(r.raw_angle_deg), closure: r.closure_norm_deg, duration: r.end_s - r.start_s,
      rest: liveTurns[r.axis] ? liveTurns[r.axis].rest_before_s : null }));
  }
  return Object.values(liveTurns).map((t) => ({ axis: t.axis, raw: Math.abs(t.angle_deg["xyz".indexOf(t.axis)]), closure: null,
    duration: t.duration_s, rest: t.rest_before_s }));
}

/** Each turn was a full turn: what the raw readings made of it, and what the calibration makes of it. */
function turnsTable(rows) {
  const off = (deg) => {
    const pct = ((deg - 360) / 360) * 100;
    return Math.abs(pct) < 0.05 ? "" : ` (${pct > 0 ? "+" : "−"}${num(Math.abs(pct), 1)}\u00a0%)`;
  };
  return h("div", null, h("h2", null, "Turns"),
    h("p", { class: "muted" }, "Each turn was one full turn, 360°, back to where it began. The raw readings show how far off the sensor was before this calibration; with it, each turn comes back to its start."),
    // on a narrow screen it scrolls in its own box, which the keyboard can reach too
    h("div", { class: "table-wrap", tabindex: "0", role: "region", "aria-label": "Turns" }, h("table", { class: "turns" },
      h("thead", null, h("tr", null, ["Full turn", "Sensor read, raw", "With this calibration: ends from its start", "Duration", "Rest before"]
        .map((t) => h("th", { scope: "col" }, t)))),
      h("tbody", null, rows.map((r) => h("tr", null,
        h("th", { scope: "row" }, AXIS_LABEL[r.axis]),
        h("td", null, `${num(r.raw, 0)}°`, h("span", { class: "pm" }, off(r.raw))),
        h("td", null, r.closure != null ? `${num(r.closure, 2)}°` : "—"),
        h("td", null, `${num(r.duration, 1)} s`),
        h("td", null, r.rest != null ? `${num(r.rest, 1)} s` : "—")))))));
}

/** Where the hand put the device back after each turn: the tilt the accelerometer saw (the heading it cannot see). */
function placementText(p) {
  if (!p) return null;
  const prior = p.heading_prior_deg != null ? `; allowed for: ${num(p.heading_prior_deg, 2)}° per turn` : "";
  if (!p.measured_by) return `not measured (no accelerometer)${prior}`;
  const each = (p.turns || []).filter((t) => t.tilt_deg != null)
    .map((t) => `${(t.axis || "?").toUpperCase()} ${num(t.tilt_deg, 2)}° ± ${num(t.tilt_std_deg, 2)}°`);
  return each.length ? `tilted ${each.join(", ")}, taken into account (the turn on the table is not measured${prior})` : null;
}

/** The raw recording, and (once calibrated) the stages it was calibrated on: uploaded together, the same result. */
function downloads(s) {
  const link = (what, file, text) => h("a", { class: "download", href: `/sessions/${s.session_id}/${what}`, download: file }, text);
  const recording = link("recording", `${s.session_id}.csv`, "Download the raw recording (CSV)");
  if (!s.result || (s.kind || "live") !== "live") return h("p", null, recording);  // live events leave the default kind out
  // the page's upload calibrates with the default method: only then is the same result promised
  const again = (s.result.method || s.method) === "closure"
    ? ". Uploaded together (Upload, with the stages as its labelled sections), they give this calibration again." : ".";
  return h("p", { class: "downloads" }, recording, " and ",
    link("sections", `${s.session_id}.sections.json`, "the stages it was calibrated on (JSON)"), h("span", { class: "muted" }, again));
}

export function detailsBlock(ctx, s) {
  const res = s.result || {};
  const plots = h("div", { class: "plots", "aria-live": "polite" }, h("p", { class: "muted" }, "Open to load the plots…"));
  const checks = h("ul", { class: "checks" }, (s.checks || []).map((c) => h("li", { class: c.ok ? "ok" : "bad" },
    icon(c.ok ? "check" : "cross"), h("span", { class: "check-state" }, c.ok ? "within" : "outside"), h("span", null, c.text))));
  const turns = turnRows(s.turns || {}, res);
  const q = res.quality || {};
  const facts = [
    ["Protocol", q.protocol ? `${q.protocol.found.summary} (found: ${q.protocol.found.name}; used: ${q.protocol.used})` : null],
    ["Method", res.method || s.method],
    ["Samples", s.samples != null ? `${s.samples} at ${num(s.sample_rate_hz || res.sample_rate_hz, 1)} Hz` : res.n_samples],
    ["Lost on the radio link", s.lost_samples != null ? `${s.lost_samples} samples` : null],
    ["Noise at rest", res.noise_dps ? `${res.noise_dps.map((v) => num(v, 3)).join(" / ")} °/s (X / Y / Z)` : null],
    ["Fit", q.chi2 != null && q.dof ? `χ²/dof = ${num(q.chi2 / q.dof, 2)} (${q.dof} dof)` : null],
    ["Gravity after each re-orientation", q.gravity_residual_rms_deg != null
      ? `${num(q.gravity_residual_rms_deg, 2)}° rms over ${(q.gravity_residual_deg || []).length} motions` : null],
    ["g-sensitivity", gSensitivityText(q.g_sensitivity, res.G)],
    ["Put back after each turn", placementText(q.placement)],
  ].filter(([, v]) => v !== null && v !== undefined);
  const det = h("details", { class: "details" },
    h("summary", null, "Details: values, checks, plots and model check"),
    h("div", { class: "details-body" },
      h("div", { class: "details-grid" },
        h("div", null, h("h2", null, "Values"), paramTable(res.k || [], res.b || [], res.uncertainty),
          h("p", { class: "muted" }, "± is one standard deviation: the uncertainty of each value.")),
        h("div", null, h("h2", null, "Checks"), checks)),
      turns.length ? turnsTable(turns) : null,
      h("dl", { class: "facts" }, facts.map(([k, v]) => h("div", null, h("dt", null, k), h("dd", null, String(v))))),
      h("h2", null, "Before and after calibration"),
      plots,
      downloads(s),
      modelCheckPanel(ctx, s.session_id)));
  let loaded = false;
  det.addEventListener("toggle", async () => {
    if (!det.open || loaded) return;
    loaded = true;
    try {
      const tr = await ctx.api.get(`/sessions/${s.session_id}/plot`, { max_points: 700 });
      fill(plots, calibrationPlots(tr));
    } catch (err) {
      loaded = false;
      fill(plots, notice("warn", "warn", `The plots could not be loaded: ${err.network ? "the service cannot be reached" : err.detail}`));
    }
  });
  return det;
}
