// A device's history: every accepted calibration with its values and who accepted it, how the
// parameters moved over time, and every session whatever its outcome.

import { AXES, AXIS_LABEL, fill, fmtDate, fmtDateTime, fmtTime, h, num, parseTime, sig } from "./dom.js";
import { icon } from "./figures.js";
import { reasonFor } from "./messages.js";
import { historyChart } from "./plots.js";

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

/** A date over its time, so a narrow column breaks between them rather than anywhere. */
function when(iso) {
  const d = parseTime(iso);
  if (!d) return "—";
  return h("time", { datetime: iso, class: "when" }, h("span", null, fmtDate(iso)), h("span", { class: "when-time" }, fmtTime(d)));
}

function calibrationTable(cals) {
  const values = (vals, unc, digits, uDigits) => vals.map((v, j) => h("span", { class: "val" }, num(v, digits),
    unc ? h("span", { class: "pm" }, ` ±${sig(unc[j], uDigits)}`) : null));
  return h("table", { class: "history calibrations" },
    h("caption", null, "Accepted calibrations, newest first"),
    h("thead", null, h("tr", null, ["Accepted", "By, how", "Scale factors k (X, Y, Z)", "Biases b, °/s (X, Y, Z)", "Recording"].map((c) => h("th", { scope: "col" }, c)))),
    h("tbody", null, cals.map((c, i) => h("tr", { class: i === 0 ? "current" : "" },
      h("td", null, when(c.accepted_at), i === 0 ? h("span", { class: "badge" }, icon("check"), "current") : null),
      h("td", { class: "source" }, h("strong", null, c.operator),
        h("span", { class: "how" }, `${c.source === "upload" ? "uploaded recording" : "guided session"} · ${c.method}`),
        c.sensor_model ? h("span", { class: "how" }, `${c.sensor_model}${c.firmware ? `, firmware ${c.firmware}` : ""}`) : null),
      h("td", { class: "num" }, values(c.k, c.uncertainty && c.uncertainty.k, 4, 1)),
      h("td", { class: "num" }, values(c.b, c.uncertainty && c.uncertainty.b, 3, 1)),
      h("td", null, c.recording_sha256 ? h("a", { href: `/sessions/${c.session_id}/recording`, download: `${c.session_id}.csv` }, "CSV") : "—")))));
}

function sessionTable(sessions) {
  return h("table", { class: "history sessions" },
    h("caption", null, "All calibration attempts, newest first"),
    h("thead", null, h("tr", null, ["Started", "Outcome", "Operator", "Kind"].map((c) => h("th", { scope: "col" }, c)))),
    h("tbody", null, sessions.map((sess) => {
      const o = outcome(sess);
      return h("tr", null,
        h("td", { class: "nowrap" }, h("a", { href: `#/session/${sess.session_id}` }, fmtDateTime(sess.started_at))),
        h("td", null, h("span", { class: `outcome ${o.cls}` }, icon(o.icon), h("span", null, o.text))),
        h("td", null, sess.operator || "—"),
        h("td", null, sess.kind === "upload" ? "uploaded recording" : "guided"));
    })));
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
    try {
      const enc = encodeURIComponent(deviceId);
      [dev, cals, sessions] = await Promise.all([
        ctx.api.get(`/devices/${enc}`), ctx.api.get(`/devices/${enc}/calibrations`), ctx.api.get(`/devices/${enc}/sessions`, { limit: 100 }),
      ]);
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
      cals.length ? [parameterCharts(cals), calibrationTable(cals)] : null,
      sessions.length ? sessionTable(sessions) : h("p", { class: "muted" }, "No calibration attempts yet."),
      dev.available && !dev.active_session ? h("div", { class: "actions" }, h("a", { class: "button primary big", href: `#/place/${encodeURIComponent(deviceId)}` }, icon("play"), `Calibrate ${name}`)) : null);
  })();
  return () => {
    alive = false;
  };
}
