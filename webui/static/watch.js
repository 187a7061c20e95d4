// Watches of a calibration on study recordings (docs/lifecycle.md, "Is the calibration still true?"): a recording
// made with the calibration in force, uploaded from the history page, says of each scale factor and bias whether it
// holds, moved (by how much, since when) or cannot be told; the history lists every watch.

import { fill, fmtDateTime, h, num } from "./dom.js";
import { icon } from "./figures.js";
import { problemLine } from "./messages.js";

const VERDICT = {
  holds: { cls: "pass", icon: "check", text: "holds" },
  moved: { cls: "fail", icon: "warn", text: "moved: calibrate again" },
  "cannot tell": { cls: "neutral", icon: "info", text: "cannot tell" },
};

/** One parameter's change in its units: "+0.12 %" for a scale factor, "+0.300 °/s" for a bias. */
function amount(p, value, signed = true) {
  if (value === null || value === undefined) return "—";
  const sign = signed && value >= 0 ? "+" : "";
  return p.name.startsWith("k") ? `${sign}${num(100 * value, 2)} %` : `${sign}${num(value, 3)} °/s`;
}

/** What a parameter's verdict says, in a line: "b_z moved by +0.300 ± 0.003 °/s, between 771 s and 830 s". */
export function parameterLine(p) {
  const axis = `${p.name[0]} ${p.name.slice(-1).toUpperCase()}`;
  if (p.verdict === "cannot tell") return `${axis}: cannot tell (${p.would_tell})`;
  const by = `${amount(p, p.change)} ± ${amount(p, p.std, false)}`;
  if (p.verdict === "holds") return `${axis} holds: ${by} from the calibration`;
  const when = p.since ? `, between ${num(p.since.after_s, 0)} s and ${num(p.since.before_s, 0)} s into the recording`
    : ", before the recording began";
  return `${axis} moved by ${by}${when}`;
}

/** The latest watch of a calibration, in a few words (beside it in the calibrations' table). */
export function watchedLine(w) {
  if (!w) return null;
  const moved = w.parameters.filter((p) => p.verdict === "moved").map((p) => `${p.name[0]} ${p.name.slice(-1).toUpperCase()}`);
  const said = { holds: "holds on a study recording", moved: `moved on a study recording: ${moved.join(", ")}`,
    "cannot tell": "a study recording could not tell" }[w.verdict];
  return h("span", { class: `how watched ${VERDICT[w.verdict].cls}` }, icon(VERDICT[w.verdict].icon), said);
}

/** The report of one watch: its verdict, each parameter's line, the evidence and what was left out. */
function report(w) {
  const v = VERDICT[w.verdict];
  const e = w.evidence;
  const temp = w.temperature_c ? `, ${num(w.temperature_c[0], 1)}–${num(w.temperature_c[1], 1)} °C` : ", no temperature column";
  return h("div", { class: "watch-report", "data-verdict": w.verdict },
    h("p", { class: `watch-verdict outcome ${v.cls}` }, icon(v.icon),
      h("span", null, `${w.recording || "The recording"}: the calibration ${v.text}`)),
    h("ul", { class: "watch-parameters" }, w.parameters.map((p) => h("li", { "data-parameter": p.name, "data-verdict": p.verdict },
      parameterLine(p)))),
    h("p", { class: "muted watch-evidence" }, `${e.rests} rests (${num(e.rest_s, 0)} s) and ${e.reorientations} re-orientations`
      + `${temp}; ${num(e.left_out.seconds, 0)} s of longer motion (walking) left out, ${num(100 * e.left_out.fraction, 0)} % of the recording.`),
    w.warnings.map((text) => h("p", { class: "form-error" }, icon("warn"), h("span", null, text))));
}

/** "Watch a study recording": a CSV made with the current calibration in force, its verdict shown and kept. */
export function watchForm(ctx, deviceId, current) {
  const file = h("input", { id: "watch-file", type: "file", accept: ".csv,text/csv", required: true });
  const out = h("div", { class: "in-force-out", "aria-live": "polite" });
  const go = h("button", { class: "button", type: "submit" }, icon("check"), "Watch");
  const form = h("form", { class: "in-force watch" },
    h("label", { for: "watch-file" }, `Does calibration #${current.id} still hold? A study recording made with it (CSV)`), file, go, out);
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const f = file.files && file.files[0];
    if (!f) {
      fill(out, h("p", { class: "form-error" }, icon("warn"), h("span", null, "Choose the recording's CSV file.")));
      return;
    }
    go.disabled = true;
    fill(out, h("p", { class: "muted" }, "Reading its rests and re-orientations…"));
    try {
      const w = await ctx.api.request("POST", `/calibrations/${current.id}/watch`, { csv: await f.text(), query: { name: f.name } });
      fill(out, report(w), h("p", null, h("a", { href: `#/history/${encodeURIComponent(deviceId)}`, class: "reload-history",
        onclick: (e) => { e.preventDefault(); ctx.go(`#/history/${encodeURIComponent(deviceId)}`, true); } }, "Show it in the history")));
    } catch (err) {
      if (err.status !== 401) fill(out, h("p", { class: "form-error" }, icon("warn"), h("span", null, problemLine(err))));
    } finally {
      go.disabled = false;
    }
  });
  return form;
}

/** Every watch of the device's calibrations, newest first. */
export function watchTable(watches) {
  return h("table", { class: "history watches" },
    h("caption", null, "Study recordings watched, newest first"),
    h("thead", null, h("tr", null, ["Watched", "Recording", "Calibration", "Verdict", "Moved, or could not be told"].map((c) => h("th", { scope: "col" }, c)))),
    h("tbody", null, watches.map((w) => {
      const v = VERDICT[w.verdict];
      const notable = w.parameters.filter((p) => p.verdict !== "holds");
      return h("tr", { "data-verdict": w.verdict },
        h("td", { class: "nowrap" }, fmtDateTime(w.at)),
        h("td", null, w.recording || "—"),
        h("td", null, `#${w.calibration_id}`),
        h("td", null, h("span", { class: `outcome ${v.cls}` }, icon(v.icon), h("span", null, v.text))),
        h("td", null, notable.length ? h("ul", { class: "watch-parameters" }, notable.map((p) => h("li", null, parameterLine(p)))) : "every one holds"));
    })));
}
