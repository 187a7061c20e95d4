// A whole kit: the wearables of one tray, turned together through one set of prompts, each one's state as a row,
// its result, and every one that passed accepted at once. The page follows the kit's event stream (a snapshot each
// time a wearable's state changes).

import { cues } from "./cues.js";
import { AXES, fill, h, num } from "./dom.js";
import { REST_PHASES, angleGauge, icon, showRest, showTurn, stillRing, trayPicture } from "./figures.js";
import { identifyButton } from "./identify.js";
import { problemLine } from "./messages.js";
import { sessionNotices } from "./notices.js";
import { ask } from "./confirm.js";
import { accuracySentence, cautionTexts } from "./readiness.js";

const ENDED = new Set(["done", "failed", "cancelled"]);
const STEPS = [["still", "Hold still"], ["turn_x", "Turn X"], ["turn_y", "Turn Y"], ["turn_z", "Turn Z"], ["computing", "Result"]];
const AXES_SHOWN = 0.0005;  // the smallest cross-axis term said: 0.05 %, shown as 0.1 %

/** The operator's choice of wearables to calibrate together: POST /kits/calibrate, then the kit's page. */
export async function startKit(ctx, devices, note) {
  try {
    const out = await ctx.api.request("POST", "/kits/calibrate", { json: { devices } });
    ctx.go(`#/kit/${out.session_id}`);
  } catch (err) {
    if (err.status !== 401) note.textContent = problemLine(err);
  }
}

function axisOf(state) {
  return state && state.startsWith("turn_") ? state.slice(5) : null;
}

// beside the tray, as on the one-wearable page: the stillness ring while a rest is counted, the angle gauge through a
// turn (both the wearable's furthest along, whose state the kit's is)
function cueKey(snap) {
  if (snap.state === "still") return "ring";
  const axis = axisOf(snap.state);
  if (!axis) return null;
  return REST_PHASES.includes(snap.phase) ? `ring:${axis}` : `gauge:${axis}`;
}

/** Where a wearable is in its turn about ``axis``: one still checking a turn the tray has left says so, not "Turn
 * about Y" beside the tray's prompt to turn about Z (``behind``: the tray is at a later step than this wearable). */
function turnText(axis, phase, behind) {
  switch (phase) {
    case "turning": case "placing": return `Turning about ${axis}`;
    case "checking": return `Checking its turn about ${axis}`;
    case "pause": return `Resting after the turn about ${axis}`;
    case "settle": return "Resting";
    default: return behind ? `No turn about ${axis} seen yet` : `Turn about ${axis}`;
  }
}

function stateText(d, notTurned, behind = false) {
  if (d.departed) return "Came apart from the kit";
  if (notTurned && d.state === "failed") return "Did not turn with the kit";
  switch (d.state) {
    case "connecting": return "Connecting…";
    case "still": return "Resting";
    case "turn_x": case "turn_y": case "turn_z": return turnText(axisOf(d.state).toUpperCase(), d.phase, behind);
    case "reconnecting": return "Link lost: reconnecting";
    case "computing": return "Computing";
    case "done": return d.passed ? `PASS${d.decision === "accepted" ? ", saved" : ""}${cautionTexts(d).length ? ", with a caution" : ""}` : "FAIL";
    case "cancelled": return "Cancelled";
    default: return "Failed";
  }
}

/** What the kit found of its sensors' axes, once calibrated: said only when a wearable's calibration holds a
 * cross-axis term that shows at one decimal of a percent (calib.kit.axes; the kit may fit a full K whose terms are
 * all but zero, and "not quite square, about 0.0 %" would say one thing and mean another). */
function axesText(snap) {
  const axes = snap.kit && snap.kit.consistency && snap.kit.consistency.axes;
  if (!axes || axes.model !== "upper-triangular" || !(axes.largest_tilt >= AXES_SHOWN)) return "";
  return `The wearables' axes are not quite square (cross-axis terms up to ${num(100 * axes.largest_tilt, 1)} %): `
    + "each one's was measured against the others' and is part of its calibration.";
}

/** The wearables that came apart, named: what to do with each is in its row, in the service's words. */
function departedText(departed) {
  const one = departed.length === 1;
  return `${departed.join(" and ")} came apart from the kit, so the kit gives ${one ? "it" : "them"} no calibration: ` +
    `${one ? "its row says" : "their rows say"} what to do.`;
}

const passedIt = (d) => d.state === "done" && d.passed;

/** "mock-2", "mock-2 and mock-3", "mock-2, mock-3 and mock-4". */
function andList(list) {
  return list.length > 1 ? `${list.slice(0, -1).join(", ")} and ${list[list.length - 1]}` : list.join("");
}

/** The kit's result for the study, as one wearable's verdict says it: which wearables are ready (with a caution when
 * a row has one) and which are not. */
function readyLine(passed, others) {
  if (!passed.length) return h("p", { class: "ready no kit-ready" }, icon("cross"), "Not ready for the study");
  const careful = passed.filter((d) => cautionTexts(d).length).map((d) => d.device_id);
  const ids = passed.map((d) => d.device_id);
  const are = (list) => (list.length === 1 ? "is" : "are");
  const said = `${andList(ids)} ${are(ids)} ready for the study`
    + (careful.length ? `, ${careful.length === ids.length && ids.length > 1 ? "each" : andList(careful)} with a caution` : "")
    + (others.length ? `; ${andList(others)} ${are(others)} not` : "");
  return h("p", { class: `ready kit-ready ${careful.length ? "caution" : "yes"}` }, icon(careful.length ? "warn" : "check"), said);
}

// what a running row says of a wearable the kit named, by the warning's code: to be seated firmly, or put in the tray
const TO_SEAT = {
  kit_moved_alone: "It moved in its slot while the rest of the kit stayed still: seat it firmly.",
  kit_not_turned: "It did not turn with the rest of the kit: put it in its slot, switched on.",
};

/** The wearables the kit named as moving alone in their slots, or not turning with the tray at all: device -> what
 * its row says (the newest). */
function movedAlone(snap) {
  return new Map((snap.warnings || []).filter((w) => TO_SEAT[w.code] && w.device_id).map((w) => [w.device_id, TO_SEAT[w.code]]));
}

/** The wearables whose rows offer Identify, for the clinician to find them in the tray: while the kit runs, those the
 * kit named (``moved``: moved in their slots, or did not turn with the tray); once it ended, those that did not pass
 * (to take out, seat again or redo). */
function toFind(snap, moved) {
  if (!ENDED.has(snap.state)) return [...moved.keys()];
  return snap.devices.filter((d) => !passedIt(d)).map((d) => d.device_id);
}

/** What a wearable's row says, as a key: its row is drawn again only when this changes (the kit's snapshots come many
 * times a second; a row drawn anew each time would be read out again by a screen reader, and could take a tap). */
function rowKey(d, { ident, moved, refusal, notTurned, behind }) {
  const k = d.result && Array.isArray(d.result.k) ? d.result.k : null;
  return JSON.stringify([d.state, stateText(d, notTurned, behind), d.passed, d.departed, d.decision, d.reason, k, moved,
    Boolean(ident), refusal, Boolean(d.accuracy)]);
}

/** A wearable's row. ``ident``: its Identify button and status line, when its protocol can blink and the clinician
 * is to find it in the tray (``toFind``); ``moved``: what its row says while the kit runs, when the kit named it
 * (moved in its slot, or did not turn with the tray), else null;
 * ``refusal``: why the whole kit could not be calibrated, said once above the rows (a row says only a reason of its
 * own); ``notTurned``: the kit left it out, its readings following none of the others'; ``behind``: the tray is at a
 * later step than this wearable. */
function deviceRow(d, { ident, moved, refusal, notTurned, behind }) {
  const ended = ENDED.has(d.state);
  const good = passedIt(d);
  const cautions = good ? cautionTexts(d) : [];
  const k = d.result && Array.isArray(d.result.k) ? d.result.k : null;
  const seat = !ended && moved;
  const find = seat || (ended && !good); // to seat now, or to take out of the tray
  return h("li", { class: "kit-device", dataset: { device: d.device_id, state: d.state, passed: String(Boolean(d.passed)), departed: String(Boolean(d.departed)) } },
    h("span", { class: "kit-name" }, d.device_id),
    h("span", { class: `kit-state ${ended ? (good ? "pass" : "fail") : ""}` },
      icon(ended ? (good ? "pass" : "fail") : d.state === "reconnecting" || seat ? "warn" : "busy"), h("span", null, stateText(d, notTurned, behind))),
    k ? h("span", { class: "kit-k" }, `k ${AXES.map((a, i) => `${a.toUpperCase()} ${num(k[i], 4)}`).join(" · ")}`) : null,
    good && d.accuracy ? h("span", { class: "kit-accuracy" }, accuracySentence(d.accuracy, d.device_id)) : null,
    cautions.length ? h("div", { class: "kit-caution", role: "note" }, h("ul", null, cautions.map((t) => h("li", null, t)))) : null,
    ended && !good && d.reason && d.reason !== refusal ? h("span", { class: "kit-reason" }, d.reason) : null,
    seat ? h("span", { class: "kit-reason kit-moved" }, moved) : null,
    find && (ended || ident) ? h("div", { class: "kit-row-actions" },
      ended ? h("a", { class: "button small kit-redo", href: `#/place/${encodeURIComponent(d.device_id)}` }, icon("redo"), "Redo alone") : null,
      ident ? ident.button : null) : null,
    find && ident ? ident.line : null);
}

/** One kit session, as the service has it. */
export function kitView(ctx, kitId) {
  ctx.title("Calibrate the kit");
  let alive = true;
  let stop = null;
  const headline = h("h1", { id: "kit-title", class: "kit-prompt" }, "Loading the kit…");
  const sub = h("p", { class: "lead kit-sub" });
  const noticeBox = h("div", { class: "notice-box kit-notice" });
  // her hands are on the tray: a tone at each prompt and the prompts read aloud, when she turns them on (the one on the
  // screen at once)
  const sound = cues({ current: () => headline.textContent });
  const notices = sessionNotices({ thing: "tray", sound }); // the kit's warnings (a knock, a turn asked again and why, ...)
  notices.attach(noticeBox);
  const runningActions = h("div", { class: "kit-running-actions" },
    h("button", { class: "button", type: "button", id: "kit-cancel", onclick: () => cancel() }, icon("stop"), "Cancel"),
    sound.controls());
  let endedSaid = false;
  const tray = h("div", { class: "kit-tray" });
  const cue = h("div", { class: "kit-cue", hidden: true });
  const picture = h("div", { class: "kit-picture" }, tray, cue);
  let live = { key: null, ring: null, gauge: null };
  // the Identify buttons of the wearables to find in the tray (``toFind``), each made once, so that its status line
  // ("mock-3 blinks its light…") stays while the rows are drawn again; ``devices``: GET /devices, asked once
  const idents = new Map();
  const asked = new Set();
  let devices = null;
  let last = null;
  const drawn = new Map(); // device -> { key, el }: each row as last drawn
  let trayKey = null;
  let guarded = ""; // the unsaved PASSes the page asks about before it is left (their devices), as last set
  const steps = h("ol", { class: "kit-steps" }, STEPS.map(([key, label]) => h("li", { dataset: { step: key } }, label)));
  const rows = h("ul", { class: "kit-devices", "aria-label": "Every wearable of the kit", "aria-live": "polite" });
  const axesNote = h("p", { id: "kit-axes", class: "kit-axes", hidden: true });
  const saved = h("p", { id: "kit-saved", role: "status" });
  const actions = h("div", { class: "actions" });
  // while the kit runs, Cancel and the sound's controls come first, as on one wearable's page (below the rows, a
  // phone had them off the screen); its result's decisions come after the rows, once they have been read
  const head = h("div", { class: "kit-head" });
  const ready = h("div", { class: "kit-ready-box" });
  const root = h("section", { class: "panel kit", "aria-labelledby": "kit-title", dataset: { state: "connecting" } },
    head, headline, ready, sub, noticeBox, picture, steps, rows, axesNote, saved, actions);
  fill(ctx.main, root);
  ctx.focusMain();

  const render = (snap) => {
    last = snap;
    root.dataset.state = snap.state;
    const running = !ENDED.has(snap.state);
    const names = snap.devices.map((d) => d.device_id);
    const axis = axisOf(snap.state);
    const drawnTray = `${names.join("\n")}|${axis}`;
    if (trayKey !== drawnTray) {
      trayKey = drawnTray;
      fill(tray, trayPicture(names, axis));
    }
    const key = running ? cueKey(snap) : null;
    if (key !== live.key) {
      live = { key, ring: key && key.startsWith("ring") ? stillRing("the tray") : null,
               gauge: key && key.startsWith("gauge") ? angleGauge(axis, "the tray") : null };
      fill(cue, live.ring || live.gauge);
      cue.hidden = !key;
    }
    if (live.ring) showRest(live.ring, snap);
    if (live.gauge) showTurn(live.gauge, snap);
    const at = STEPS.findIndex(([key]) => key === snap.state);
    for (const [i, li] of [...steps.children].entries()) {
      li.classList.toggle("done", !running || (at >= 0 && i < at));
      if (i === at) {
        if (li.getAttribute("aria-current") !== "step") li.setAttribute("aria-current", "step");
      } else if (li.hasAttribute("aria-current")) li.removeAttribute("aria-current");
    }
    const moved = movedAlone(snap);
    drawRows(snap, moved, at);
    const find = toFind(snap, moved).filter((id) => !asked.has(id));
    if (find.length) identifyLater(find);
    const axesSaid = running ? "" : axesText(snap);
    if (axesNote.textContent !== axesSaid) axesNote.textContent = axesSaid;
    axesNote.hidden = !axesSaid;
    if (running) {
      notices.update(snap);
      const said = snap.prompt || "…";
      if (headline.textContent !== said) {
        headline.textContent = said;
        sound.tone("step");
        sound.say(said);
      }
      const together = `${names.length === 2 ? "Both" : `All ${names.length}`} wearables are turned together, in their tray.`;
      if (sub.textContent !== together) sub.textContent = together;
      if (head.firstChild !== runningActions) fill(head, runningActions);
      return;
    }
    fill(head, null);
    notices.stop();
    fill(noticeBox, null);
    const passed = snap.devices.filter((d) => passedIt(d) && !d.departed);
    const open = passed.filter((d) => !d.decision);
    // leaving PASSes nobody accepted loses them from their wearables: ask first, as for one wearable's
    const openKey = open.map((d) => d.device_id).join(" ");
    if (openKey !== guarded) {
      guarded = openKey;
      ctx.guardLeave(open.length ? () => ask({
        title: "Leave without saving?",
        text: `${open.length === 1 ? "This PASS is" : "These PASSes are"} not saved: ${andList(open.map((d) => d.device_id))} `
          + `${open.length === 1 ? "keeps its" : "keep their"} previous calibration until you press “Accept all that passed”.`,
        stay: "Stay and save", leave: "Leave without saving",
      }) : null);
    }
    headline.textContent = snap.state === "cancelled" ? "The kit's calibration was cancelled"
      : passed.length ? `Kit calibrated: ${passed.length} of ${names.length} passed` : "No wearable of the kit passed";
    if (!endedSaid) {
      endedSaid = true;
      sound.tone(passed.length ? "done" : "warn");
      sound.say(headline.textContent);
    }
    sub.textContent = snap.kit && snap.kit.departed.length ? departedText(snap.kit.departed)
      : snap.kit && snap.kit.refusal ? snap.kit.refusal : "";
    const notPassed = snap.devices.filter((d) => !passedIt(d) || d.departed).map((d) => d.device_id);
    fill(ready, snap.state === "cancelled" ? null : readyLine(passed, notPassed));
    fill(actions,
      open.length ? h("button", { class: "button primary", type: "button", id: "kit-accept", onclick: accept }, icon("save"),
        `Accept all that passed (${open.length})`) : null,
      h("a", { class: "button", href: "#/devices" }, icon("back"), "Device list"));
  };

  /** Every wearable's row, each drawn again only when what it says has changed, in the kit's order (``at``: the
   * kit's step in STEPS). */
  const drawRows = (snap, moved, at) => {
    const refusal = (snap.kit && snap.kit.refusal) || null;
    const left = new Set((snap.kit && snap.kit.consistency && snap.kit.consistency.not_turned) || []);
    const els = snap.devices.map((d) => {
      const step = STEPS.findIndex(([key]) => key === d.state);
      const row = { ident: idents.get(d.device_id), moved: moved.get(d.device_id) || null, refusal,
                    notTurned: left.has(d.device_id), behind: step >= 0 && at > step };
      const key = rowKey(d, row);
      const was = drawn.get(d.device_id);
      if (was && was.key === key) return was.el;
      const el = deviceRow(d, row);
      drawn.set(d.device_id, { key, el });
      return el;
    });
    const same = els.length === rows.children.length
      && snap.devices.every((d, i) => rows.children[i].dataset.device === d.device_id);
    if (!same) fill(rows, els);
    else els.forEach((el, i) => { if (rows.children[i] !== el) rows.children[i].replaceWith(el); });
  };

  const follow = () => {
    stop = ctx.api.follow(kitId, (snap) => {
      if (!alive) return;
      render(snap);
      if (ENDED.has(snap.state)) halt();
    }, (link) => {
      if (alive) ctx.streamLink(link);
    });
  };

  const halt = () => {
    if (stop) stop();
    stop = null;
    ctx.banner(null);
  };

  /** Which of these wearables can blink (GET /devices, asked once), then the rows again with their buttons. */
  async function identifyLater(ids) {
    for (const id of ids) asked.add(id);
    try {
      devices = devices || ctx.api.get("/devices").then((list) => new Map(list.map((dev) => [dev.id, dev])));
      const known = await devices;
      let made = false;
      for (const id of ids) {
        const ident = known.has(id) ? identifyButton(ctx.api, known.get(id)) : null;
        if (ident) {
          ident.button.classList.add("small"); // beside "Redo alone" in the row, of its size
          idents.set(id, ident);
        }
        made = made || Boolean(ident);
      }
      if (alive && made) render(last);
    } catch {
      // without the list a row keeps "Redo alone", which opens the wearable's own page and its Identify
      devices = null;
    }
  }

  async function load() {
    try {
      const snap = await ctx.api.get(`/sessions/${kitId}`);
      if (!alive) return;
      render(snap);
      if (!ENDED.has(snap.state)) follow();
    } catch (err) {
      if (alive && err.status !== 401) ctx.problem(err, "show the kit");
    }
  }

  async function cancel() {
    try {
      render(await ctx.api.request("POST", `/kits/${kitId}/cancel`));
    } catch (err) {
      saved.textContent = problemLine(err);
    }
  }

  async function accept() {
    const btn = document.getElementById("kit-accept");
    if (btn) btn.disabled = true;
    try {
      const out = await ctx.api.request("POST", `/kits/${kitId}/accept`);
      const kept = out.calibrations.map((c) => c.device_id).join(", ");
      const not = Object.keys(out.not_accepted);
      saved.textContent = `Saved as the current calibration of ${kept}.${not.length ? ` Not saved: ${not.join(", ")}.` : ""}`;
      render(await ctx.api.get(`/sessions/${kitId}`));
    } catch (err) {
      saved.textContent = problemLine(err);
      if (btn) btn.disabled = false;
      if (err.status === 409) { // decided meanwhile (another operator): show the kit as it now stands
        try {
          render(await ctx.api.get(`/sessions/${kitId}`));
        } catch { /* the sentence above says enough */ }
      }
    }
  }

  load();
  return () => {
    alive = false;
    notices.stop();
    halt();
  };
}
