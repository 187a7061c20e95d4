// A device's history: every accepted calibration with its values and who accepted it, how the
// parameters moved over time, and every session whatever its outcome.

import { AXES, AXIS_LABEL, fill, fmtDate, fmtDateTime, fmtTime, h, num, parseTime, sig } from "./dom.js";
import { icon } from "./figures.js";
import { problemLine, reasonFor } from "./messages.js";
import { historyChart, orientationPlots, temperatureChart } from "./plots.js";
import { watchForm, watchTable, watchedLine } from "./watch.js";

const MARKERS = { x: "circle", y: "square", z: "triangle" };

function outcome(sess) {
  if (sess.decision === "accepted") return { cls: "pass", icon: "save", text: "accepted" };
  if (sess.state === "done" && sess.decision === "discarded") return { cls: "neutral", icon: "trash", text: "passed, discarded" };
  if (sess.state === "done") return { cls: "pass", icon: "pass", text: "passed, not saved" };
  if (sess.state === "cancelled") return { cls: "neutral", icon: "stop", text: "cancelled" };
  if (sess.state === "failed") return { cls: "fail", icon: "fail", text: `failed: ${reasonFor(sess.reason_code).title.toLowerCase()}` };
  return { cls: "neutral", icon: "clock", text: sess.state };
}

function parameterCharts(cals) {
  const ordered = [...cals].sort((a, b) => parseTime(a.accepted_at) - parseTime(b.accepted_at));
  const when = ordered.map((c) => parseTime(c.accepted_at));
  const series = (key) => AXES.map((a, i) => ({
    y: ordered.map((c) => c[key][i]), err: ordered.map((c) => (c.uncertainty && c.uncertainty[key] ? c.uncertainty[key][i] : 0)),
    label: `${AXIS_LABEL[a]} axis`, cls: `ax-${a}`, marker: MARKERS[a],
  }));
  return h("div", { class: "plots" },
    historyChart({ title: "Scale factors k", caption: "how much each axis over- or under-reads (1 is perfect), calibration after calibration", yLabel: "k", when, series: series("k") }),
    historyChart({ title: "Biases b", caption: "the rate each axis reads at rest, in true °/s", yLabel: "°/s", when, series: series("b") }));
}

/** k and b against the sensor's temperature: each calibration made at a known one, and the line the device's watches
 * measured about the current calibration (null when there is neither a model nor two such calibrations). */
function temperatureCharts(cals, model) {
  const known = cals.filter((c) => c.identity && typeof c.identity.temperature_c === "number");
  if (!model && known.length < 2) return null;
  const cur = cals[0];
  const series = (key, at) => AXES.map((a, i) => ({
    points: known.map((c) => [c.identity.temperature_c, c[key][i]]),
    line: model ? model.watched_c.map((T) => [T, at(cur[key][i], i, T - model.temp_ref_c)]) : null,
    label: `${AXIS_LABEL[a]} axis`, cls: `ax-${a}`, marker: MARKERS[a],
  }));
  const from = model ? [model.watches ? `${model.watches} watched recording${model.watches === 1 ? "" : "s"}` : null,
    model.calibrations ? `${model.calibrations} calibrations of its power-up` : null].filter(Boolean).join(" and ") : "";
  const said = model ? `; the lines: what ${from} measured, about calibration #${model.calibration_id} at ${num(model.temp_ref_c, 1)} °C` : "";
  return h("div", { class: "plots temperature" },
    temperatureChart({ title: "Scale factors k against temperature", caption: `each calibration at the temperature it was made${said}`, yLabel: "k",
      series: series("k", (v, i, dT) => v * (1 + model.scale_tc_per_c[i] * dT)) }),
    temperatureChart({ title: "Biases b against temperature", caption: `in true °/s${said}`, yLabel: "°/s",
      series: series("b", (v, i, dT) => v + model.bias_tc_dps_per_c[i] * dT) }));
}

/** A date over its time, so a narrow column breaks between them rather than anywhere. */
function when(iso) {
  const d = parseTime(iso);
  if (!d) return "—";
  return h("time", { datetime: iso, class: "when" }, h("span", null, fmtDate(iso)), h("span", { class: "when-time" }, fmtTime(d)));
}

const SOURCE = { upload: "uploaded recording", import: "imported file", live: "guided session" };

/** The sensor, power-up and temperature a calibration was measured at, as far as it was recorded. */
function identityLine(c) {
  const id = c.identity || {};
  const parts = [
    id.serial ? `serial ${id.serial}` : null,
    id.boot_count != null ? `power-up #${id.boot_count}` : id.booted_at ? `switched on ${fmtDateTime(id.booted_at)}` : null,
    id.temperature_c != null ? `${num(id.temperature_c, 1)} °C` : null,
  ].filter(Boolean);
  return parts.length ? h("span", { class: "how identity" }, parts.join(" · ")) : null;
}

/** Optional fields saying which sensor and power-up a recording comes from (the service prefers that power-up's
 * calibration and refuses another sensor's). */
function recordingFields(prefix) {
  const serial = h("input", { id: `${prefix}-serial`, type: "text", maxlength: "128", autocomplete: "off", placeholder: "optional" });
  const boot = h("input", { id: `${prefix}-boot`, type: "number", min: "0", max: "4294967295", step: "1", inputmode: "numeric", placeholder: "optional" });
  return {
    fields: [h("label", { for: `${prefix}-serial` }, "sensor serial"), serial, h("label", { for: `${prefix}-boot` }, "power-up #"), boot],
    query: () => ({ serial: serial.value.trim() || undefined, boot_count: boot.value === "" ? undefined : boot.value }),
  };
}

/** The latest verification turn of a calibration, in a few words. */
function verifiedLine(v) {
  if (!v) return null;
  return h("span", { class: `how verified ${v.confirmed ? "ok" : "off"}` }, icon(v.confirmed ? "check" : "warn"),
    `verified: ${num(v.calibrated_deg, 1)}° ± ${sig(v.uncertainty_deg, 1)}° (raw ${num(v.raw_deg, 1)}°)`);
}

function calibrationTable(cals, verifications = [], watches = []) {
  const values = (vals, unc, digits, uDigits) => vals.map((v, j) => h("span", { class: "val" }, num(v, digits),
    unc ? h("span", { class: "pm" }, ` ±${sig(unc[j], uDigits)}`) : null));
  return h("table", { class: "history calibrations" },
    h("caption", null, "Accepted calibrations, newest first"),
    h("thead", null, h("tr", null, ["Accepted", "By, how", "Scale factors k (X, Y, Z)", "Biases b, °/s (X, Y, Z)", "Files"].map((c) => h("th", { scope: "col" }, c)))),
    h("tbody", null, cals.map((c, i) => h("tr", { class: i === 0 ? "current" : "" },
      h("td", null, when(c.accepted_at), i === 0 ? h("span", { class: "badge" }, icon("check"), "current") : null),
      h("td", { class: "source" }, h("strong", null, c.operator),
        h("span", { class: "how" }, `${SOURCE[c.source] || c.source} · ${c.method}`),
        c.sensor_model ? h("span", { class: "how" }, `${c.sensor_model}${c.firmware ? `, firmware ${c.firmware}` : ""}`) : null,
        identityLine(c), verifiedLine(verifications.find((v) => v.calibration_id === c.id)),
        watchedLine(watches.find((w) => w.calibration_id === c.id))),
      h("td", { class: "num" }, values(c.k, c.uncertainty && c.uncertainty.k, 4, 1)),
      h("td", { class: "num" }, values(c.b, c.uncertainty && c.uncertainty.b, 3, 1)),
      h("td", null, h("div", { class: "files" },
        c.recording_sha256 ? h("a", { href: `/sessions/${c.session_id}/recording`, download: `${c.session_id}.csv`, title: "the raw recording" }, "recording") : null,
        h("a", { href: `/calibrations/${c.id}?format=imucal`, download: `${c.device_id}-calibration-${c.id}.imucal.json`, title: "for imucal's load_calibration_info" }, "imucal"),
        h("a", { href: `/calibrations/${c.id}?format=csv`, download: `${c.device_id}-calibration-${c.id}.csv`, title: "k, b (and K, G) with their uncertainties" }, "CSV")))))));
}

function sessionTable(sessions) {
  return h("table", { class: "history sessions" },
    h("caption", null, "All calibration attempts, newest first"),
    h("thead", null, h("tr", null, ["Started", "Outcome", "Operator", "Kind"].map((c) => h("th", { scope: "col" }, c)))),
    h("tbody", null, sessions.map((sess) => {
      const o = sess.kind === "verify" ? { cls: sess.passed ? "pass" : "fail", icon: sess.passed ? "pass" : "warn", text: sess.passed ? "verified" : "verification off" }
        : sess.kind === "watch" ? { cls: sess.passed ? "pass" : "fail", icon: sess.passed ? "pass" : "warn", text: sess.passed ? "no move found" : "moved" }
          : outcome(sess);
      return h("tr", null,
        h("td", { class: "nowrap" }, ["live", "upload"].includes(sess.kind)
          ? h("a", { href: `#/session/${sess.session_id}` }, fmtDateTime(sess.started_at)) : fmtDateTime(sess.started_at)),
        h("td", null, h("span", { class: `outcome ${o.cls}` }, icon(o.icon), h("span", null, o.text))),
        h("td", null, sess.operator || "—"),
        h("td", null, { upload: "uploaded recording", import: "imported file", verify: "verification turn", watch: "study recording watched" }[sess.kind] || "guided"));
    })));
}

/** A line under a form saying what went wrong (or what to be warned of). */
function formProblem(text) {
  return h("p", { class: "form-error" }, icon("warn"), h("span", null, text));
}

const noneBy = (deviceId) => `No calibration of ${deviceId} had been accepted by then.`;

/** "Which calibration was in force at…": a moment in, the calibration the service says was in force then out. */
function inForceForm(ctx, deviceId, cals) {
  const input = h("input", { id: "in-force-at", type: "datetime-local", step: "1", required: true });
  const out = h("div", { class: "in-force-out", "aria-live": "polite" });
  const ask = h("button", { class: "button", type: "submit" }, icon("search"), "Find");
  const rec = recordingFields("in-force");
  const form = h("form", { class: "in-force" },
    h("label", { for: "in-force-at" }, "Which calibration was in force at"), input, rec.fields, ask, out);
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const when = input.value ? new Date(input.value) : null;
    if (!when || Number.isNaN(when.getTime())) {
      fill(out, formProblem("Choose a date and a time."));
      return;
    }
    const first = Math.min(...cals.map((c) => parseTime(c.accepted_at).getTime()));
    if (when.getTime() < first) {
      // known from the list already: no need to ask the service for what it would answer 404
      fill(out, formProblem(noneBy(deviceId)));
      return;
    }
    try {
      const cal = await ctx.api.get(`/devices/${encodeURIComponent(deviceId)}/calibration`, { at: when.toISOString(), ...rec.query() });
      const n = cals.findIndex((c) => c.id === cal.id);
      const age = cal.in_force.age_days;
      fill(out, h("p", { class: "in-force-answer" }, icon("check"),
        h("span", null, `Calibration #${cal.id}${n >= 0 ? ` (row ${n + 1} below)` : ""}, accepted by ${cal.operator} on ${fmtDateTime(cal.accepted_at)}: `,
          `${age < 1 ? `${num(Math.abs(age) * 24, 1)} hours` : `${num(age, 1)} days`} ${age < 0 ? "later, in the same power-up" : "old then"}.`,
          cal.in_force.chosen_by === "same_power_up" ? " Measured in that power-up." : "")),
        cal.in_force.warnings.map((w) => formProblem(w)));
    } catch (err) {
      if (err.status === 401) return;
      fill(out, formProblem(err.status === 404 && !rec.query().serial ? noneBy(deviceId) : problemLine(err)));
    }
  });
  return form;
}

/** "Correct a study recording": a CSV in, the recording corrected by the calibration in force when it was made out. */
function applyForm(ctx, deviceId) {
  const file = h("input", { id: "apply-file", type: "file", accept: ".csv,text/csv", required: true });
  const when = h("input", { id: "apply-at", type: "datetime-local", step: "1" });
  const out = h("div", { class: "in-force-out", "aria-live": "polite" });
  const go = h("button", { class: "button", type: "submit" }, icon("save"), "Correct");
  const rec = recordingFields("apply");
  const orient = h("input", { id: "apply-orientation", type: "checkbox" });
  const form = h("form", { class: "in-force apply" },
    h("label", { for: "apply-file" }, "Correct a study recording (CSV)"), file,
    h("label", { for: "apply-at" }, "recorded at"), when, rec.fields,
    h("label", { class: "check", for: "apply-orientation" }, orient, "show its orientation before and after"), go, out);
  let url = null;
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const f = file.files && file.files[0];
    if (!f) {
      fill(out, formProblem("Choose the recording's CSV file."));
      return;
    }
    go.disabled = true;
    try {
      const at = when.value ? new Date(when.value).toISOString() : undefined;
      const csv = await f.text();
      const path = `/devices/${encodeURIComponent(deviceId)}`;
      const res = await ctx.api.request("POST", `${path}/apply`, { csv, query: { at, ...rec.query() }, raw: true });
      if (url) URL.revokeObjectURL(url);
      url = URL.createObjectURL(new Blob([res.text], { type: "text/csv" }));
      const name = f.name.replace(/\.csv$/i, "") + ".calibrated.csv";
      const warnings = JSON.parse(res.headers.get("X-Gyrocal-Warnings") || "[]");
      fill(out, h("p", { class: "in-force-answer" }, icon("check"), h("span", null,
        `Corrected with calibration #${res.headers.get("X-Gyrocal-Calibration-Id")} (${res.headers.get("X-Gyrocal-Corrected")}). `,
        h("a", { class: "download", href: url, download: name }, `Download ${name}`))),
      warnings.map((w) => formProblem(w)));
      if (orient.checked) {
        out.append(h("p", { class: "muted" }, "Estimating the orientation…"));
        const o = await ctx.api.request("POST", `${path}/orientation`, { csv, query: { at, ...rec.query() } });
        out.lastChild.replaceWith(h("p", { class: "in-force-answer" }, icon("check"), h("span", null,
          `With the calibration the orientation ends ${num(o.final_difference_deg, 1)}° from where the raw readings put it (${o.method}).`)),
        h("div", { class: "plots orientation" }, orientationPlots(o)));
      }
    } catch (err) {
      if (err.status !== 401) fill(out, formProblem(problemLine(err)));
    } finally {
      go.disabled = false;
    }
  });
  return form;
}

/** "Import a calibration file": imucal's or gyrocal's JSON into the history, marked as imported. */
function importForm(ctx, deviceId) {
  const file = h("input", { id: "import-file", type: "file", accept: ".json,application/json", required: true });
  const out = h("div", { class: "in-force-out", "aria-live": "polite" });
  const go = h("button", { class: "button", type: "submit" }, icon("save"), "Import");
  const rec = recordingFields("import");
  const form = h("form", { class: "in-force import" },
    h("label", { for: "import-file" }, "Import a calibration file (imucal or gyrocal JSON)"), file, rec.fields, go, out);
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const f = file.files && file.files[0];
    if (!f) {
      fill(out, formProblem("Choose the calibration file."));
      return;
    }
    go.disabled = true;
    try {
      await ctx.api.request("POST", `/devices/${encodeURIComponent(deviceId)}/calibrations`,
        { jsonText: await f.text(), query: { name: f.name, ...rec.query() } });
      ctx.go(`#/history/${encodeURIComponent(deviceId)}`);
    } catch (err) {
      if (err.status !== 401) fill(out, formProblem(problemLine(err)));
    } finally {
      go.disabled = false;
    }
  });
  return form;
}

export function historyView(ctx, deviceId) {
  let alive = true;
  ctx.title(`History of ${deviceId}`);
  const body = h("div", { class: "history-body", "aria-busy": "true" }, h("p", { class: "muted" }, "Loading the history…"));
  fill(ctx.main, h("section", { class: "panel wide", "aria-labelledby": "history-title" },
    h("div", { class: "panel-head" },
      h("div", null, h("h1", { id: "history-title" }, `History of ${deviceId}`),
        h("p", { class: "lead" }, "Every accepted calibration is kept; the newest is the current one.")),
      h("a", { class: "button", href: "#/devices" }, icon("back"), "Device list")),
    body));
  ctx.focusMain();

  (async () => {
    let dev;
    let cals;
    let sessions;
    let verifications;
    let watches;
    let model = null;
    try {
      const enc = encodeURIComponent(deviceId);
      [dev, cals, sessions, verifications, watches] = await Promise.all([
        ctx.api.get(`/devices/${enc}`), ctx.api.get(`/devices/${enc}/calibrations`), ctx.api.get(`/devices/${enc}/sessions`, { limit: 100 }),
        ctx.api.get(`/devices/${enc}/verifications`), ctx.api.get(`/devices/${enc}/watches`),
      ]);
      if (cals.length && watches.length) model = await ctx.api.get(`/devices/${enc}/temperature-model`);
    } catch (err) {
      if (alive && err.status !== 401) ctx.problem(err, `load the history of ${deviceId}`);
      return;
    }
    if (!alive) return;
    const name = dev.name || deviceId;
    ctx.main.querySelector("#history-title").textContent = `History of ${name}`;
    body.setAttribute("aria-busy", "false");
    const cur = cals[0];
    fill(body,
      h("p", { class: `current-line ${cur ? "calibrated" : "never"}` }, icon(cur ? "check" : "info"),
        h("span", null, cur ? `Current calibration: accepted by ${cur.operator} on ${fmtDateTime(cur.accepted_at)}.` : `${name} has no accepted calibration yet.`)),
      cals.length ? [parameterCharts(cals), temperatureCharts(cals, model), calibrationTable(cals, verifications, watches), inForceForm(ctx, deviceId, cals), applyForm(ctx, deviceId),
        watchForm(ctx, deviceId, cur)] : null,
      watches.length ? watchTable(watches) : null,
      importForm(ctx, deviceId),
      sessions.length ? sessionTable(sessions) : h("p", { class: "muted" }, "No calibration attempts yet."),
      dev.available && !dev.active_session ? h("div", { class: "actions" }, h("a", { class: "button primary big", href: `#/place/${encodeURIComponent(deviceId)}` }, icon("play"), `Calibrate ${name}`)) : null);
  })();
  return () => {
    alive = false;
  };
}
