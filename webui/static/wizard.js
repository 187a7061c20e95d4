// Steps 1-7: place the device, hold still, the three turns, the result and the decision. The page
// shows the service's session as it streams it (SSE); everything it shows comes from the service.

import { AXES, AXIS_LABEL, fill, fmtDateTime, h } from "./dom.js";
import { ask } from "./confirm.js";
import { TURN_SUMMARY, turnGuide } from "./guide.js";
import { cues } from "./cues.js";
import { REST_PHASES, angleGauge, icon, notice, placePicture, showRest, showTurn, stillRing, turnAnimation, turnTiles } from "./figures.js";
import { sessionNotices } from "./notices.js";
import { identifyButton } from "./identify.js";
import { STEP_LABELS, TURN_FAULTS, headline, reasonFor, requestProblem, stepOf, subline, timeLeft } from "./messages.js";
import { detailsBlock, paramTable } from "./details.js";
import { readiness } from "./readiness.js";
import { verifyTurn } from "./verify.js";
import { writeBack } from "./writeback.js";

const END_STATES = new Set(["done", "failed", "cancelled"]);
// wider than a phone (style.css), the running session's stage takes the height left under the prompt
const FILLS_HEIGHT = window.matchMedia("(min-width: 481px)");

// -- shared pieces -------------------------------------------------------------------------------
/** "Step n of 7" and the bar of steps; stopped=true marks step n as the one where the calibration stopped. */
function stepHeader(step, button, stopped = false) {
  const no = h("p", { class: "stepno" });
  const bar = h("ol", { class: "stepbar", "aria-hidden": "true" });
  const head = h("header", { class: "wiz-head" }, h("div", { class: "wiz-steps" }, no, bar), button || null);
  head.update = (n) => {
    if (head.dataset.step === String(n)) return;
    head.dataset.step = String(n);
    no.replaceChildren(stopped ? `Stopped at step ${n} of ${STEP_LABELS.length} ` : `Step ${n} of ${STEP_LABELS.length} `,
      h("span", { class: "step-name" }, `· ${STEP_LABELS[n - 1]}`));
    bar.replaceChildren(...STEP_LABELS.map((label, i) => {
      const st = i + 1 < n ? "done" : i + 1 === n ? (stopped ? "stopped" : "current") : "todo";
      const mark = st === "done" ? icon("check") : st === "stopped" ? icon("cross") : String(i + 1);
      return h("li", { class: st }, h("span", { class: "dot" }, mark), h("span", { class: "label" }, label));
    }));
  };
  head.update(step);
  return head;
}

/** The step a stopped session had reached, from what it recorded (when the page did not see it run). */
function stoppedStep(s) {
  const n = Object.keys(s.turns || {}).length;
  const code = s.reason_code;
  if (code === "connect_failed") return 1;
  if (code === "moved_during_pause") return Math.min(5, Math.max(3, 2 + n));
  if (n >= 3) return 6;
  if (n === 0 && (code === "not_still" || code === "cancelled")) return 2;
  return 3 + n;
}

function cancelButton(onclick, label = "Cancel") {
  return h("button", { class: "button cancel", type: "button", onclick }, icon("cross"), label);
}

/** A session another gateway runs, followed from this page: it is cancelled there, where the device is. */
function remoteLink(remote, sid) {
  const href = remote.url ? `${remote.url}/#/session/${encodeURIComponent(sid)}` : "#/fleet";
  return h("a", { class: "button remote", href }, icon("play"), `Open on ${remote.gateway}`);
}

function deviceLabel(dev, id) {
  return (dev && dev.name) || id;
}

// -- step 1: place the device ------------------------------------------------------------------
export function placeView(ctx, deviceId) {
  let alive = true;
  ctx.title("Place the device");
  const message = h("div", { class: "inline-problem", "aria-live": "assertive" });
  const start = h("button", { class: "button primary big", type: "button", disabled: true }, icon("play"), "Start");
  const cancel = cancelButton(() => ctx.go("#/devices"));
  const sub = h("p", { class: "sub" }, "Flat, face up, one edge against the block. Press Start, then hands off.");
  const overview = h("div", { class: "overview" },
    h("h2", null, "What happens: 3 turns, about 30 s"),
    h("ol", { class: "overview-list" },
      h("li", null, h("span", { class: "ov-thumb still" }, icon("clock")), h("span", null, h("strong", null, "Rest"), " 3 s, hands off")),
      AXES.map((a) => h("li", null, h("span", { class: "ov-thumb" }, turnGuide(a, { small: true })),
        h("span", null, h("strong", null, `Turn ${AXIS_LABEL[a]}`), ` ${TURN_SUMMARY[a].toLowerCase()}`)))),
    h("p", { class: "muted" }, "After each turn, back against the block. The screen shows each step as you go."));
  const title = h("h1", { class: "instruction" }, "Place it against the block");
  const identSlot = h("div", { class: "identify-slot" });
  const identLine = h("div", { class: "identify-line" });
  fill(ctx.main, h("section", { class: "wizard", "aria-labelledby": "place-title", dataset: { state: "place" } },
    stepHeader(1, cancel),
    h("div", { class: "prompt", "aria-live": "polite" }, Object.assign(title, { id: "place-title" }), sub),
    h("div", { class: "stage two" }, placePicture(),
      h("div", { class: "place-side" },
        h("p", { class: "device-name" }, icon("info"), h("span", { class: "dev-label" }, deviceId)),
        overview, h("div", { class: "place-actions" }, start, identSlot, cues().controls()), identLine, message))));
  ctx.focusMain();

  let device = null;
  ctx.api.get(`/devices/${encodeURIComponent(deviceId)}`).then((dev) => {
    if (!alive) return;
    device = dev;
    if (dev.active_session) {
      ctx.go(`#/session/${dev.active_session}`, true);
      return;
    }
    ctx.main.querySelector(".dev-label").textContent = `${deviceLabel(dev, deviceId)}${dev.sensor_model ? ` · ${dev.sensor_model}` : ""}`;
    if (!dev.available) {
      fill(message, notice("error", "offline", `${deviceLabel(dev, deviceId)} cannot be reached by the service. Switch it on, bring it near and scan for it from the device list.`));
      return;
    }
    const ident = identifyButton(ctx.api, dev);
    if (ident) {
      fill(identSlot, ident.button);
      fill(identLine, ident.line);
    }
    start.disabled = false;
    start.focus();
  }).catch((err) => alive && err.status !== 401 && ctx.problem(err, `find the device ${deviceId}`));

  start.addEventListener("click", async () => {
    start.disabled = true;
    start.replaceChildren(icon("clock"), "Starting…");
    try {
      const out = await ctx.api.post(`/devices/${encodeURIComponent(deviceId)}/calibrate`, {});
      if (alive) ctx.go(`#/session/${out.session_id}`, true);
    } catch (err) {
      if (!alive || err.status === 401) return;
      start.disabled = false;
      start.replaceChildren(icon("play"), "Start");
      const p = requestProblem(err, "start the calibration");
      let parts = [notice("error", "warn", `${p.title}: ${p.text}`), h("p", null, p.fix)];
      if (err.status === 409) {
        try {
          const dev = await ctx.api.get(`/devices/${encodeURIComponent(deviceId)}`);
          if (dev.active_session) {
            const name = deviceLabel(dev, deviceId);
            parts = [notice("error", "busy", `${name} is already being calibrated on another screen.`),
              h("p", null, "Join that calibration to follow it here, or wait until it ends."),
              h("a", { class: "button", href: `#/session/${dev.active_session}` }, icon("play"), "Go to that calibration"),
              h("p", { class: "fineprint" }, err.detail)];
          }
        } catch {
          // the message above already says what happened
        }
      }
      fill(message, parts);
    }
  });
  return () => {
    alive = false;
    void device;
  };
}

// -- steps 2-7: the running session and its end ------------------------------------------------
export function sessionView(ctx, sid) {
  const api = ctx.api;
  let alive = true;
  let snap = null;
  let device = null;
  let stop = null;
  let ui = null;
  let endedKey = null;
  let lastStep = null; // the step this page saw the session at, before it ended
  let lastAxis = null; // the turn a lost connection interrupted
  const sound = cues(); // tones and spoken prompts, when she has turned them on
  const notices = sessionNotices({ sound });

  const closeStream = () => {
    if (stop) stop();
    stop = null;
  };

  const apply = (s) => {
    if (!alive || !s || s.session_id !== sid) return;
    if (snap && s.event_id && snap.event_id && s.event_id <= snap.event_id) return;
    snap = s;
    if (END_STATES.has(s.state)) {
      closeStream();
      ctx.banner(null);
      const key = `${s.state}:${s.decision || ""}`;
      if (key !== endedKey) {
        endedKey = key;
        ui = null;
        renderEnded(s);
        if (!s.decision) {
          const verdict = ctx.main.querySelector("#verdict-title");
          sound.tone(s.state === "done" ? "done" : "warn");
          sound.say(verdict ? verdict.textContent : "");
        }
      }
      return;
    }
    if (s.kit_id) { // turned with the rest of its tray: the kit's page has the tray's prompts
      closeStream();
      ctx.go(`#/kit/${s.kit_id}`, true);
      return;
    }
    renderRunning(s);
  };

  const follow = () => {
    stop = api.follow(sid, apply, (link) => {
      if (alive) ctx.streamLink(link);
    });
  };

  const refresh = async () => {
    try {
      apply({ ...(await api.get(`/sessions/${sid}`)), event_id: null });
    } catch (err) {
      if (alive && err.status !== 401) ctx.problem(err, "load the calibration");
    }
  };

  // -- running ----------------------------------------------------------------------------------
  const doCancel = async (btn) => {
    btn.disabled = true;
    try {
      apply({ ...(await api.post(`/sessions/${sid}/cancel`)), event_id: null });
    } catch (err) {
      if (!alive || err.status === 401) return;
      btn.disabled = false;
      if (err.status === 409) await refresh();
      else notices.show(notice("error", "warn", `${requestProblem(err, "cancel").title}: ${err.detail}`), true);
    }
  };

  const buildRunning = (s) => {
    const cancel = s.remote ? remoteLink(s.remote, sid) : cancelButton(() => doCancel(cancel));
    const head = stepHeader(stepOf(s) || 1, cancel);
    const title = h("h1", { class: "instruction", id: "instruction" });
    const sub = h("p", { class: "sub" });
    const where = s.remote ? h("p", { class: "remote-note", role: "note" }, icon("info"),
      `This calibration runs on gateway ${s.remote.gateway}, where the wearable is; this page follows it live.`) : null;
    const noticeBox = h("div", { class: "notice-box" });
    const limit = h("p", { class: "time-left", role: "timer", hidden: true });
    const stage = h("div", { class: "stage" });
    const tiles = turnTiles();
    const prompt = h("div", { class: "prompt", "aria-live": "polite", "aria-atomic": "true" }, title, sub);
    const root = h("section", { class: "wizard live", "aria-labelledby": "instruction" },
      head, where, prompt, noticeBox, limit, stage, tiles);
    fill(ctx.main, root);
    ctx.focusMain();
    ui = { root, head, prompt, title, sub, limit, stage, tiles, key: null, ring: null, gauge: null, remote: Boolean(s.remote) };
    notices.attach(noticeBox);
  };

  const stageKey = (s) => {
    // the gauge stays while the device is put down (placing): the turn view changes only once it rests (checking)
    if (s.state.startsWith("turn_")) {
      if (s.phase === "returning") return `back:${s.axis}`;
      // put down (placing), the rest's ring takes the turn's picture's place beside the gauge and counts from the stop
      if (s.phase === "placing") return `turn:${s.axis}:placing`;
      return REST_PHASES.includes(s.phase) ? `rest:${s.axis}:${s.phase}` : `turn:${s.axis}`;
    }
    return s.state;
  };

  const buildStage = (s) => {
    ui.ring = null;
    ui.gauge = null;
    const dev = deviceLabel(device, s.device_id);
    let content;
    switch (ui.key.split(":")[0]) {
      case "connecting":
        content = [placePicture(), h("div", { class: "side-note" }, h("span", { class: "spinner", "aria-hidden": "true" }), h("p", null, `Connecting to ${dev}…`))];
        break;
      case "still":
        ui.ring = stillRing();
        content = [ui.ring, placePicture()];
        break;
      case "turn":
        ui.gauge = angleGauge(s.axis);
        if (ui.key.endsWith(":placing")) {
          ui.ring = stillRing();
          content = [h("div", { class: "how-to" }, ui.ring), ui.gauge];
        } else {
          content = [h("div", { class: "how-to" }, turnGuide(s.axis), h("p", { class: `axis-caption ax-${s.axis}` }, `Turn ${AXIS_LABEL[s.axis]}`)), ui.gauge];
        }
        break;
      case "back": // asked again with the device off its place: put back before the turn
        content = [placePicture(), h("div", { class: "side-note" }, h("p", { class: "recorded redo" }, icon("redo"),
          `Then turn ${AXIS_LABEL[s.axis]} again`))];
        break;
      case "rest": {
        ui.ring = stillRing();
        // settling after a lost connection or a moved device: the turn is kept if it was recorded already
        const recorded = s.phase === "checking"
          ? h("p", { class: "recorded checking" }, icon("clock"), `Checking turn ${AXIS_LABEL[s.axis]}…`)
          : s.turns && s.turns[s.axis]
            ? h("p", { class: "recorded" }, icon("check"), `Turn ${AXIS_LABEL[s.axis]} recorded`)
            : h("p", { class: "recorded redo" }, icon("redo"), `Turn ${AXIS_LABEL[s.axis]} will be asked again`);
        content = [ui.ring, h("div", { class: "side-note" }, recorded, placePicture())];
        break;
      }
      case "reconnecting":
        content = [h("div", { class: "big-icon link-lost" }, icon("link")), h("div", { class: "side-note" }, h("span", { class: "spinner", "aria-hidden": "true" }), h("p", null, `Waiting for ${dev} to reconnect…`))];
        break;
      case "computing":
      default:
        content = [h("div", { class: "side-note center" }, h("span", { class: "spinner large", "aria-hidden": "true" }), h("p", null, "Computing the calibration from the recording…"))];
    }
    ui.stage.className = `stage two stage-${ui.key.split(":")[0]}`;
    fill(ui.stage, content);
  };

  /** On a screen whose stage takes the height left under the prompt, the prompt keeps the tallest height it had in
   * this stage (``key``: a turn from its prompt through the device put down), so that the gauge does not change size
   * when the turn stops and the headline grows (277 to 237 px on a desktop); a new stage starts afresh. The prompt is
   * measured only when its words changed (``reworded``) or the stage did: not at each of the many snapshots a second. */
  let heldFor = null;
  const shownDone = new Set(); // the turns the tiles have shown done in this session
  const holdStageSize = (key, reworded) => {
    const fresh = heldFor !== key;
    if (fresh) {
      heldFor = key;
      ui.prompt.style.minHeight = "";
    }
    if (!(fresh || reworded) || !FILLS_HEIGHT.matches) return;
    const now = ui.prompt.offsetHeight;
    if (now > (parseFloat(ui.prompt.style.minHeight) || 0)) ui.prompt.style.minHeight = `${now}px`;
  };

  const renderRunning = (s) => {
    if (!ui || ui.remote !== Boolean(s.remote)) buildRunning(s);
    ui.root.dataset.state = s.state;
    ui.root.dataset.phase = s.phase || "";
    ui.head.update(stepOf(s) || ui.head.dataset.step || 1);
    lastStep = Number(ui.head.dataset.step);
    const key = stageKey(s);
    if (key !== ui.key) {
      if (ui.key !== null) sound.tone("step");
      ui.key = key;
      buildStage(s);
    }
    const dev = deviceLabel(device, s.device_id);
    const t = headline(s, dev);
    const sub = subline(s);
    const reworded = ui.title.textContent !== t || ui.sub.textContent !== sub;
    if (ui.title.textContent !== t) {
      ui.title.textContent = t;
      ctx.title(t);
      sound.say(t);
    }
    if (ui.sub.textContent !== sub) ui.sub.textContent = sub;
    // a turn, from its prompt to the device put down, is one stage for the prompt's height (the gauge's size)
    holdStageSize(s.state.startsWith("turn_") && ["ready", "turning", "placing"].includes(s.phase) ? s.state : key, reworded);
    const left = timeLeft(s);
    ui.limit.hidden = !left;
    if (left && ui.limit.textContent !== left) ui.limit.textContent = left;
    if (ui.ring) showRest(ui.ring, s);
    if (ui.gauge) showTurn(ui.gauge, s);
    if (s.state.startsWith("turn_")) lastAxis = s.axis;
    const done = Object.keys(s.turns || {});
    for (const a of done) shownDone.add(a);
    const active = s.state.startsWith("turn_") ? s.axis : s.state === "reconnecting" ? lastAxis : null;
    ui.tiles.update(done, active, Boolean(active) && shownDone.has(active) && !done.includes(active));
    ui.tiles.hidden = !(s.state.startsWith("turn_") || s.state === "still" || s.state === "reconnecting");
    notices.update(s);
  };

  // -- ended ------------------------------------------------------------------------------------
  const renderEnded = (s) => {
    notices.stop();
    if (s.decision) ctx.guardLeave(null); // decided here or on another page
    if (s.decision === "accepted") return savedView(s);
    if (s.decision === "discarded") return discardedView(s);
    if (s.state === "done") return resultView(s, true);
    if (s.state === "failed" && s.reason_code === "out_of_tolerance" && s.result) return resultView(s, false);
    if (s.state === "cancelled") return stoppedView(s, "cancelled");
    return stoppedView(s, s.reason_code);
  };

  const endLayout = (s, step, verdict, body, headerButton, stopped = false) => {
    const root = h("section", { class: "wizard ended", "aria-labelledby": "verdict-title", dataset: { state: s.state, decision: s.decision || "", reason: s.reason_code || "" } },
      stepHeader(step, headerButton || cancelButton(() => ctx.go("#/devices"), "Close"), stopped), verdict, ...body);
    fill(ctx.main, root);
    ctx.focusMain();
    return root;
  };

  const verdictEl = (kind, iconName, text, kicker, under = null) => h("div", { class: `verdict ${kind}`, role: "status" },
    icon(iconName, { cls: "verdict-icon" }),
    h("div", null, kicker ? h("p", { class: "kicker" }, kicker) : null, h("h1", { id: "verdict-title" }, text), under));

  const discard = async () => {
    if (snap && snap.decision) return snap;
    const out = await api.post(`/sessions/${sid}/discard`, {});
    ctx.guardLeave(null);
    return out;
  };

  const resultView = (s, pass) => {
    const dev = deviceLabel(device, s.device_id);
    const message = h("div", { class: "inline-problem", "aria-live": "assertive" });
    const buttons = [];
    const busy = (on) => buttons.forEach((b) => (b.disabled = on));
    const act = async (what, fn) => {
      busy(true);
      try {
        await fn();
      } catch (err) {
        if (!alive || err.status === 401) return;
        busy(false);
        const p = requestProblem(err, what);
        fill(message, notice("error", "warn", `${p.title}: ${p.text}`), h("p", null, p.fix));
        if (err.status === 409) setTimeout(refresh, 1500);
      }
    };
    const redo = h("button", { class: `button ${pass ? "" : "primary big"}`, type: "button" }, icon("redo"), "Redo");
    redo.addEventListener("click", () => act("redo the calibration", async () => {
      await discard();
      ctx.go(`#/place/${encodeURIComponent(s.device_id)}`);
    }));
    const drop = h("button", { class: "button", type: "button" }, icon("trash"), "Discard");
    drop.addEventListener("click", () => act("discard the result", async () => apply({ ...(await discard()), event_id: null })));
    buttons.push(redo, drop);
    let accept = null;
    if (pass) {
      accept = h("button", { class: "button primary big accept", type: "button" }, icon("save"), "Accept & save");
      accept.addEventListener("click", () => act("save the calibration", async () => {
        accept.replaceChildren(icon("clock"), "Saving…");
        try {
          const out = await api.post(`/sessions/${sid}/accept`, {});
          ctx.guardLeave(null);
          endedKey = `${s.state}:accepted`;
          snap = { ...s, decision: "accepted", calibration_id: out.calibration.id };
          savedView(snap, out.calibration);
        } catch (err) {
          accept.replaceChildren(icon("save"), "Accept & save");
          throw err;
        }
      }));
      buttons.push(accept);
    }
    const failures = (s.checks || []).filter((c) => !c.ok).map((c) => c.text);
    const summary = readiness(s, dev, pass);
    // a recording turned about some axes only calibrates those: incomplete, never the device's calibration
    const missing = (((s.result || {}).quality || {}).undetermined_axes || []).map((a) => a.toUpperCase());
    const incomplete = !pass && missing.length > 0;
    const verdict = pass ? "PASS" : incomplete ? "INCOMPLETE" : "FAIL";
    // a FAIL says what the service found and which turn to redo, in its words (server.live.guidance)
    const sentence = pass
      ? `The gyroscope of ${dev} is calibrated within the tolerances.`
      : incomplete
        ? `Only part of the gyroscope of ${dev} is calibrated: there was no usable full turn about ${missing.join(" and ")}, `
          + `so ${missing.length === 1 ? "its scale factor is" : "their scale factors are"} not determined.`
        : s.reason || `The result is outside the tolerances: ${failures.join("; ")}.`;
    const next = pass
      ? "Press “Accept & save” to make it the device's calibration, or Redo if anything went wrong during the turns."
      : incomplete
        ? `It cannot become the device's calibration: record the protocol again, turning the device a full 360° about ${missing.join(" and ")} too.`
        : reasonFor("out_of_tolerance").fix;
    ctx.title(verdict);
    // leaving a PASS nobody accepted loses it from the device: ask first (Close, a link, Back, a reload, closing
    // the tab), with staying as the safe answer
    if (pass && !(snap && snap.decision)) {
      ctx.guardLeave(() => ask({
        title: "Leave without saving?",
        text: `This PASS is not saved: ${dev} keeps its previous calibration until you press “Accept & save”.`,
        stay: "Stay and save", leave: "Leave without saving",
      }));
    }
    const close = cancelButton(() => ctx.go("#/devices"), "Close");
    const kind = pass ? (summary.near.length || summary.departed.length ? "pass near-limit" : "pass") : "fail";
    endLayout(s, 6, verdictEl(kind, pass ? "pass" : "fail", verdict, null, summary.ready), [
      ...summary.parts,
      // on a PASS the decision comes first, with what it means under it; a FAIL says why before what to do
      pass ? null : h("p", { class: "sentence" }, sentence),
      pass ? null : h("p", { class: "next" }, next),
      h("div", { class: "actions split" }, h("div", { class: "actions" }, redo, drop), accept),
      message,
      pass ? h("p", { class: "sentence" }, sentence, " ", h("span", { class: "next-inline" }, next)) : null,
      detailsBlock(ctx, s),
    ], close);
  };

  const savedView = async (s, cal) => {
    ctx.title("Saved");
    const dev = deviceLabel(device, s.device_id);
    const meta = h("p", { class: "next" }, "Loading the saved record…");
    const values = h("div", { class: "saved-values" });
    const writeSlot = h("div", { class: "writeback" });
    const verifySlot = h("div", { class: "verify-turn" });
    endLayout(s, 7, verdictEl("saved", "pass", "Saved"), [
      h("p", { class: "sentence" }, `${dev} now uses this calibration.`),
      meta, values, verifySlot, writeSlot,
      h("div", { class: "actions" },
        h("a", { class: "button primary big", href: "#/devices" }, icon("play"), "Calibrate another device"),
        h("a", { class: "button", href: `#/history/${encodeURIComponent(s.device_id)}` }, icon("history"), `History of ${dev}`)),
    ]);
    if (!cal) {
      try {
        const all = await api.get(`/devices/${encodeURIComponent(s.device_id)}/calibrations`);
        cal = all.find((c) => c.session_id === sid) || null;
      } catch (err) {
        if (err.status === 401) return;
      }
    }
    if (!alive) return;
    if (!cal) {
      meta.textContent = "The calibration was accepted.";
      return;
    }
    meta.classList.add("saved-meta");
    meta.replaceChildren(icon("user"), h("span", null, h("strong", { class: "saved-by" }, `Accepted by ${cal.operator}`), " on ",
      h("time", { datetime: cal.accepted_at }, fmtDateTime(cal.accepted_at)), `, for ${cal.device_id}.`));
    fill(values, paramTable(cal.k, cal.b, cal.uncertainty));
    if (s.kind !== "upload") {
      const check = verifyTurn(api, cal.id);
      fill(verifySlot, h("p", null, "To check it, put the device back against the block and verify with one more full turn, about any axis (optional)."),
        check.button, check.status);
    }
    if (device && device.write_back) {
      const write = writeBack(api, s.device_id, cal.id);
      fill(writeSlot, h("p", null, `${dev} can hold this calibration itself, for its own use; its stream stays raw.`), write.button, write.line);
    }
  };

  const discardedView = async (s) => {
    ctx.title("Result discarded");
    const dev = deviceLabel(device, s.device_id);
    const keeps = h("p", { class: "sentence" }, `${dev} keeps its previous calibration.`);
    endLayout(s, 6, verdictEl("neutral", "trash", "Result discarded"), [
      keeps,
      h("div", { class: "actions" },
        h("a", { class: "button primary big", href: `#/place/${encodeURIComponent(s.device_id)}` }, icon("redo"), "Calibrate again"),
        h("a", { class: "button", href: "#/devices" }, icon("back"), "Device list")),
    ]);
    try {
      // the device's record says whether it has a calibration (asking for a missing one would be a 404)
      const cur = (await api.get(`/devices/${encodeURIComponent(s.device_id)}`)).current_calibration;
      if (!alive) return;
      keeps.textContent = cur
        ? `${dev} keeps its current calibration, accepted by ${cur.operator} on ${fmtDateTime(cur.accepted_at)}.`
        : `${dev} has no calibration yet: nothing was saved.`;
    } catch {
      // the sentence above already says what matters
    }
  };

  const stoppedView = (s, code) => {
    const r = reasonFor(code, s);
    const dev = deviceLabel(device, s.device_id);
    const cancelled = code === "cancelled";
    const step = lastStep || stoppedStep(s);
    // a turn done wrong: show again how that turn is made
    const axis = TURN_FAULTS.has(code) && step >= 3 && step <= 5 ? AXES[step - 3] : null;
    ctx.title(r.title);
    const lost = s.warnings && s.warnings.length ? h("details", { class: "details" }, h("summary", null, "What happened during the calibration"),
      h("ul", { class: "warning-list" }, s.warnings.map((w) => h("li", null, w.message)))) : null;
    const text = h("div", null,
      h("p", { class: "sentence plain" }, cancelled ? `The calibration of ${dev} was cancelled.` : s.reason || r.title),
      h("p", { class: "next" }, h("strong", null, "What to do: "), r.fix),
      h("div", { class: "actions" },
        h("a", { class: "button primary big", href: `#/place/${encodeURIComponent(s.device_id)}` }, icon("redo"), "Start again"),
        h("a", { class: "button", href: "#/devices" }, icon("back"), "Device list")));
    endLayout(s, step, verdictEl(cancelled ? "neutral" : "fail", r.icon, r.title, cancelled ? null : "FAIL · calibration stopped"), [
      axis ? h("div", { class: "stop-body" }, text, h("div", { class: "stop-figure" }, turnAnimation(axis))) : text,
      lost,
      h("p", { class: "fineprint" }, `Session ${sid} · ${s.state}${s.reason_code ? ` (${s.reason_code})` : ""} · ${fmtDateTime(s.ended_at || s.started_at)}`),
    ], null, true);
  };

  // -- start --------------------------------------------------------------------------------------
  (async () => {
    let first;
    try {
      first = await api.get(`/sessions/${sid}`);
    } catch (err) {
      if (alive && err.status !== 401) ctx.problem(err, "load the calibration");
      return;
    }
    const named = api.get(`/devices/${encodeURIComponent(first.device_id)}`).then((dev) => {
      device = dev;
    }, () => {
      device = null; // the id is enough to go on
    });
    if (END_STATES.has(first.state)) await named; // the result speaks of the device by its name
    if (!alive) return;
    // a running session is followed at once (its ring and gauge move on while the device's name is fetched); the
    // name replaces the id at the next event
    apply({ ...first, event_id: null });
    if (!END_STATES.has(first.state)) follow();
  })();

  return () => {
    alive = false;
    notices.stop();
    closeStream();
  };
}
