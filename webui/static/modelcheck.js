// The model check in a result's details: the session's recording against recordings simulated from
// the calibration model (GET /sessions/{id}/diagnosis). Plain words first, the evidence below.

import { fill, h, num, sig } from "./dom.js";
import { icon } from "./figures.js";

const POLL_MS = 400;
const MISMATCH_ROWS = 8;

// each effect of the diagnosis catalogue in plain words: a title and what it means for the sensor
const EFFECTS = {
  bias_drift: { title: "Drifting zero reading", text: "The reading at rest changed steadily during the recording, as when a sensor warms up." },
  bias_instability: { title: "Wandering zero reading", text: "The reading at rest wandered back and forth during the recording." },
  axis_misalignment: { title: "Axes not square", text: "A turn about one axis also shows a little on the others: the sensor's axes are not exactly at right angles." },
  g_sensitivity: { title: "Sensitive to gravity", text: "The rotation reading changes with how the device lies relative to gravity." },
  scale_asymmetry: { title: "Direction-dependent scale", text: "Turns one way read differently from turns the other way." },
  scale_nonlinearity: { title: "Speed-dependent scale", text: "Fast turns read differently from slow ones." },
  saturation: { title: "Readings clipped", text: "Some turns were faster than the gyroscope can measure: its readings hit their limit." },
  sample_loss: { title: "Samples lost", text: "Samples were lost between the device and the service." },
  placement_error: { title: "Not put back in place", text: "After some turns the device did not rest exactly where it was before." },
  clock_error: { title: "Device clock off", text: "The device's sample clock runs at a slightly different rate than it states." },
};

// the unit of a mismatch's value, from its statistic's name (docs/diagnosis.md, "Features")
const UNITS = [["still_rate", " °/s"], ["closure", "°"], ["tilt", "°"], ["lost_samples", " samples"], ["samples_at_full_scale", " samples"]];
const unitOf = (statistic) => (UNITS.find(([p]) => String(statistic).startsWith(p)) || [null, ""])[1];

const effectTitle = (name) => (EFFECTS[name] ? EFFECTS[name].title : name.replaceAll("_", " "));

function readsUrl(api, path) {
  const url = new URL(path, location.origin);
  if (api.authReads && api.token) url.searchParams.set("access_token", api.token);
  return url.pathname + url.search;
}

/** The largest shift of the calibration, in its standard deviations, when the effects are modelled. */
function largestShift(recal) {
  const s = recal && recal.shift_sigma;
  if (!s) return null;
  let best = null;
  for (const key of ["k", "b"]) {
    (s[key] || []).forEach((v, i) => {
      if (typeof v === "number" && Number.isFinite(v) && (!best || Math.abs(v) > Math.abs(best.v))) {
        best = { v, name: `${key === "k" ? "the scale factor" : "the zero offset"} of ${"XYZ"[i]}` };
      }
    });
  }
  return best;
}

function verdict(d) {
  const found = d.effects.length;
  const odd = d.unexplained.length;
  if (!found && !odd) {
    return h("div", { class: "mc-verdict ok" }, icon("pass", { cls: "mc-verdict-icon" }),
      h("div", null, h("p", { class: "mc-verdict-title" }, "The recording looks like the simulation"),
        h("p", null, "Nothing unexplained: the calibration model (a scale factor and a zero offset per axis) accounts for all this recording shows.")));
  }
  const names = d.effects.map((e) => effectTitle(e.name).toLowerCase());
  const title = found
    ? `Found ${found === 1 ? "an effect" : `${found} effects`} the calibration model leaves out`
    : "The recording differs from the simulation";
  const parts = [];
  if (found) parts.push(`This recording shows: ${names.join(", ")}.`);
  if (odd) parts.push(found ? "Part of the difference is not explained by any known effect (below)." : "No known effect explains the difference (below).");
  const shift = largestShift(d.recalibration);
  if (found && shift) {
    parts.push(Math.abs(shift.v) < 2
      ? "Taking it into account hardly changes the calibration (less than 2 standard deviations)."
      : `Taking it into account would change the calibration by up to ${num(Math.abs(shift.v), 1)} standard deviations (${shift.name}).`);
  }
  return h("div", { class: "mc-verdict warn" }, icon("warn", { cls: "mc-verdict-icon" }),
    h("div", null, h("p", { class: "mc-verdict-title" }, title), h("p", null, parts.join(" "))));
}

function effectsList(d) {
  if (!d.effects.length) return null;
  return h("div", null, h("h3", null, "Effects found"),
    h("ul", { class: "mc-effects" }, d.effects.map((e) => {
      const fit = e.fit || {};
      const ev = e.evidence || {};
      return h("li", { class: "mc-effect", dataset: { effect: e.name } },
        h("p", { class: "mc-effect-title" }, icon("warn"), h("strong", null, effectTitle(e.name)), h("code", null, e.name)),
        EFFECTS[e.name] ? h("p", null, EFFECTS[e.name].text) : null,
        ev.summary ? h("p", { class: "mc-evidence" }, h("span", { class: "mc-label" }, "Evidence: "), ev.summary) : null,
        (ev.rivals || []).map((t) => h("p", { class: "mc-rival" },
          h("span", { class: "mc-label" }, `Told apart from ${effectTitle(t.rival).toLowerCase()}: `), `${t.summary}.`)),
        h("p", { class: "mc-fit" }, h("span", { class: "mc-label" }, "Fit (lower is better): "),
          `${sig(fit.before, 3)} without it → ${sig(fit.after, 3)} with it`));
    })));
}

function unexplainedList(d) {
  if (!d.unexplained.length) return null;
  return h("div", null, h("h3", null, "Not explained"),
    h("ul", { class: "mc-list" }, d.unexplained.map((u) => h("li", null, icon("info"), h("span", null, u.description)))));
}

function mismatchTable(d) {
  const rows = d.mismatches || [];
  const check = d.simulation_check || {};
  const summary = check.features
    ? (check.outside_before ? `${check.outside_before} of the ${check.features} features of the recording lie outside what the simulations produce`
      : `None of the ${check.features} features of the recording lies outside what the simulations produce`) +
      (check.outside_after !== null && check.outside_after !== undefined ? `; ${check.outside_after} once the effects found are simulated too.` : ".")
    : null;
  if (!rows.length) {
    return h("div", null, h("h3", null, "Recording against simulation"),
      h("p", { class: "mc-ok" }, icon("check"), h("span", null, summary || "Every feature of the recording lies within what the simulations produce.")));
  }
  return h("div", null, h("h3", null, "Recording against simulation"),
    summary ? h("p", null, summary) : null,
    h("table", { class: "mc-mismatches" },
      h("caption", null, "Where the recording lies outside its simulations (the 95 % range of recordings simulated from the model)"),
      h("thead", null, h("tr", null, ["Where", "Recording", "Simulated range", "p-value"].map((t) => h("th", { scope: "col" }, t)))),
      h("tbody", null, rows.slice(0, MISMATCH_ROWS).map((m) => h("tr", null,
        h("th", { scope: "row" }, m.where),
        h("td", { class: "num" }, `${sig(m.observed, 3)}${unitOf(m.statistic)}`),
        h("td", { class: "num" }, `${sig(m.simulated_range[0], 2)} to ${sig(m.simulated_range[1], 2)}${unitOf(m.statistic)}`),
        h("td", { class: "num" }, sig(m.p_value, 2)))))),
    rows.length > MISMATCH_ROWS ? h("p", { class: "muted" }, `and ${rows.length - MISMATCH_ROWS} more in the full report.`) : null);
}

function notIdentifiable(d) {
  if (!d.not_identifiable.length) return null;
  return h("div", null, h("h3", null, "Not identifiable with this protocol"),
    h("p", { class: "muted" }, "What a recording like this one cannot show, or shows only when it is large, and what would show it."),
    h("ul", { class: "mc-list" }, d.not_identifiable.map((n) => h("li", null, icon("info"),
      h("span", null, h("strong", null, `${effectTitle(n.name)}: `), n.reason)))));
}

/** The panel: a button, then the verdict in plain words and the evidence beneath it. */
export function modelCheckPanel(ctx, sid) {
  const api = ctx.api;
  const button = h("button", { class: "button", type: "button" }, icon("search"), "Check the model against simulation");
  const status = h("div", { class: "mc-status", role: "status", "aria-live": "polite" });
  const result = h("div", { class: "mc-result" });
  const panel = h("section", { class: "modelcheck", "aria-labelledby": `mc-title-${sid}`, dataset: { state: "idle" } },
    h("h2", { id: `mc-title-${sid}` }, "Model check"),
    h("p", { class: "muted" }, "Compares this recording with recordings simulated from the calibration model, to find physics the model leaves out."),
    button, status, result);

  const busyView = (p) => {
    const fraction = p && typeof p.fraction === "number" ? p.fraction : 0;
    const words = p && p.state === "queued" ? "Waiting for another check to finish…" : "Simulating the recording and comparing…";
    let bar = status.querySelector("progress");
    if (!bar) {
      bar = h("progress", { max: "1", value: "0", "aria-label": "Model check progress" });
      fill(status, h("div", { class: "mc-busy" }, h("span", { class: "spinner small", "aria-hidden": "true" }), h("span", { class: "mc-busy-text" }), bar));
    }
    bar.value = fraction;
    status.querySelector(".mc-busy-text").textContent = `${words} ${Math.round(fraction * 100)} %`;
  };

  const run = async () => {
    button.disabled = true;
    button.hidden = true;
    panel.dataset.state = "running";
    fill(result);
    busyView(null);
    let done = false;
    const poll = async () => {
      while (!done) {
        await new Promise((r) => setTimeout(r, POLL_MS));
        if (done) return;
        try {
          const p = await api.get(`/sessions/${sid}/diagnosis/progress`);
          if (!done && (p.state === "queued" || p.state === "running")) busyView(p);
        } catch {
          return; // the check itself reports what went wrong
        }
      }
    };
    poll();
    try {
      const d = await api.get(`/sessions/${sid}/diagnosis`);
      done = true;
      panel.dataset.state = "done";
      panel.dataset.verdict = d.effects.length ? "effects" : d.unexplained.length ? "unexplained" : "clean";
      const v = verdict(d);
      fill(status, h("span", { class: "visually-hidden" }, `Model check finished: ${v.querySelector(".mc-verdict-title").textContent}.`));
      fill(result, v, effectsList(d), unexplainedList(d), mismatchTable(d), notIdentifiable(d),
        h("p", null, h("a", { class: "download", href: readsUrl(api, `/sessions/${sid}/diagnosis/report`), target: "_blank", rel: "noopener" },
          "Open the full report with its plots (new tab)")));
    } catch (err) {
      done = true;
      panel.dataset.state = "error";
      button.disabled = false;
      button.hidden = false;
      button.replaceChildren(icon("redo"), "Try the model check again");
      if (err.status === 401) return;
      const why = err.network ? "the service cannot be reached" : err.detail;
      fill(status, h("div", { class: "notice warn" }, icon("warn"), h("span", null, `The model check could not be done: ${why}`)));
    }
  };
  button.addEventListener("click", run);
  return panel;
}
