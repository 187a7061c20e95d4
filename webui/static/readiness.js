// What a result means for the study, in a clinician's words: ready or not, how much better the device now
// measures a turn, and which value passed close to its limit. The engineer's values stay in the details.

import { AXIS_LABEL, h, num } from "./dom.js";
import { icon } from "./figures.js";

const ax = (a) => AXIS_LABEL[a] || String(a || "").toUpperCase();

/** The decimals a figure of degrees is read with: 0.01° and 0.2° with theirs, 59° without. */
function decimals(v) {
  return v < 0.095 ? 2 : v < 9.5 ? 1 : 0;
}

/** Degrees people read, with ``d`` decimals (by default the figure's own). */
function degrees(v, d = decimals(v)) {
  if (typeof v !== "number" || !Number.isFinite(v)) return "—";
  return `${num(Math.max(v, 10 ** -d), d)}°`;
}

// A full turn measured this much better or worse is no change that matters: a fifth of the 0.25° a full turn must
// close to, and about 1.4e-4 in a scale factor
const SAME_DEG = 0.05;

/** How much better a full turn measures, against what the device used until now: its calibration in force, or
 * its raw readings when it had none. Both figures are rounded alike; a new calibration no better than the one in
 * use says so. */
export function accuracySentence(acc, dev) {
  if (!acc) return null;
  // figures of one size (both under 10°) are read with the same decimals, the finer's; 0.02° beside 58° each its own
  const alike = Math.max(acc.after_deg, acc.before_deg) < 9.5 ? Math.max(decimals(acc.after_deg), decimals(acc.before_deg)) : undefined;
  const after = degrees(acc.after_deg, alike);
  const before = degrees(acc.before_deg, alike);
  if (acc.before_with !== "calibration") return `${dev} now measures a full turn to within ${after}; uncalibrated, it was up to ${before} off.`;
  const used = `the calibration it used until now${acc.before_calibration_id ? ` (#${acc.before_calibration_id})` : ""}`;
  if (acc.before_deg - acc.after_deg >= SAME_DEG) return `${dev} now measures a full turn to within ${after}; with ${used}, it was up to ${before} off.`;
  const verdict = acc.after_deg - acc.before_deg >= SAME_DEG ? "the new one is no better" : "the new one changes nothing that matters";
  return `${dev} measures a full turn to within ${after} with this calibration and to within ${before} with ${used}: ${verdict}.`;
}

/** What a scale factor means in the sensor's own terms. g = K m: the true rate is k times the reading, so a true full
 * turn reads 360°/k, low when k > 1 and high when k < 1; ``limit`` is the scale factors' allowed range [low, high]. */
export function readsSentence(axis, k, limit) {
  const reads = 360 / k;
  const percent = Math.round(Math.abs(reads / 360 - 1) * 100);
  const direction = percent === 0 ? "true" : reads < 360 ? `${percent} % low` : `${percent} % high`;
  const allowed = Array.isArray(limit) ? ` (from ${Math.round(360 / limit[1])}° to ${Math.round(360 / limit[0])}° is allowed)` : "";
  return `The ${axis} axis reads ${direction}: a full turn shows as ${Math.round(reads)}° instead of 360°${allowed}.`;
}

/** A few words for a check that passed close to its limit. */
function nearLimitText(c) {
  const a = ax(c.axis);
  switch (c.name) {
    case "k":
      return readsSentence(a, c.value, c.limit);
    case "b":
      return `The ${a} axis reads ${num(Math.abs(c.value), 1)} °/s while still (at most ${num(c.limit, 0)} °/s is allowed).`;
    case "k_std":
    case "b_std":
      return `The ${a} axis's value is less certain than usual: smoother turns give a firmer result.`;
    case "closure":
      return `Turn ${a} did not bring the device back exactly to its start (${degrees(c.value)}; at most ${degrees(c.limit)} is allowed).`;
    default:
      return c.text;
  }
}

/** Why a PASS comes with a caution, a sentence each: the values close to their limits, then how it departs from the
 * device's earlier calibrations (``s``: a session's snapshot). */
export function cautionTexts(s) {
  return [...nearLimits(s.checks).map(nearLimitText), ...(s.departures || []).map((d) => d.text)];
}

/** The checks that passed within 20 % of their limit. */
export function nearLimits(checks) {
  return (checks || []).filter((c) => c.ok && c.near_limit);
}

/** The PASS or FAIL screen's plain summary: ``ready`` (ready or not, for the verdict box) and ``parts`` (the
 * accuracy gained and the values near a limit, under it). */
export function readiness(s, dev, pass) {
  const near = pass ? nearLimits(s.checks) : [];
  const departed = s.departures || [];
  const sensorNear = near.some((c) => c.name === "k" || c.name === "b");
  const caution = near.length > 0 || departed.length > 0;
  const ready = h("p", { class: `ready ${pass ? (caution ? "caution" : "yes") : "no"}` },
    icon(pass ? (caution ? "warn" : "check") : "cross"),
    pass ? (caution ? "Ready for the study, with a caution" : "Ready for the study") : "Not ready for the study");
  const accuracy = pass ? accuracySentence(s.accuracy, dev) : null;
  return {
    near,
    departed,
    ready,
    parts: [
      accuracy ? h("p", { class: "accuracy" }, accuracy) : null,
      departed.length ? h("div", { class: "near-limits departures", role: "note" },
        h("p", { class: "near-title" }, icon("warn"), `Not like ${dev}'s earlier calibrations`),
        h("ul", null, departed.map((d) => h("li", { dataset: { departure: `${d.name}:${d.axis}` } }, d.text))),
        h("p", { class: "near-next" }, "A sensor that was dropped or knocked changes like this. Check the device; accept only if you are sure it is fine.")) : null,
      near.length ? h("div", { class: "near-limits", role: "note" },
        h("p", { class: "near-title" }, icon("warn"), near.length === 1 ? "One value is close to its limit" : `${near.length} values are close to their limits`),
        h("ul", null, near.map((c) => h("li", { dataset: { check: `${c.name}:${c.axis || ""}` } }, nearLimitText(c)))),
        h("p", { class: "near-next" }, sensorNear
          ? "The calibration corrects this. If a later calibration fails, have the device checked."
          : "Redo the calibration if you can; otherwise the result may be used.")) : null,
    ],
  };
}
