// The notice under a running session's prompt, on both pages (one wearable, and a kit's tray): the session's newest
// warning while it is still true, else, while a rest is counted, that the thing held is moving.

import { fill } from "./dom.js";
import { notice } from "./figures.js";

const WARNING_SHOW_MS = 10000;
const WARNING_ICON = { moved: "hand", hint: "info", link_lost: "link", link_restored: "link", moved_during_pause: "hand",
  no_data: "link", data_resumed: "link", service_late: "clock", kit_moved_alone: "hand" };
const INFO = new Set(["link_restored", "hint", "data_resumed", "service_late"]);

/**
 * The notices of one running session. ``thing``: what the clinician holds ("device", or "tray" for a kit, whose
 * warnings the service composes: a fault is the tray's only when the kit asks the turn again, else the wearable's own,
 * named by it); ``sound``: the page's cues (a tone and the warning read aloud), if any.
 * Returns ``attach(box)`` (the element to show them in, again whenever the page builds it anew), ``update(snap)``
 * (each running snapshot), ``show(el, sticky)`` (a message of the page's own, kept a while when sticky) and
 * ``stop()`` (the session ended or the page left).
 */
export function sessionNotices({ thing = "device", sound = null } = {}) {
  const moving = `The ${thing} is moving. Hold it still against the block: the ring fills again once it is still.`;
  let box = null;
  let last = null;
  let seen = null; // how many warnings the page has seen (on (re)load, the old ones are history)
  let shown = null; // the warning on show, and until when
  let seenAttempt = null; // the try of the current turn, as the last snapshot said
  let timer = null;

  const showWarning = (s, w, retry) => {
    const kind = INFO.has(w.code) ? "info" : "warn";
    const el = notice(kind, WARNING_ICON[w.code] || "warn", w.message, retry ? `Attempt ${s.attempt} of ${s.max_attempts}:` : null);
    if (shown && shown.retry && kind === "info" && s.state === shown.state) {
      // a hint while a turn asked again waits: the reason stays (she has not acted on it yet), the hint beneath it
      fill(box, shown.el, el);
    } else {
      shown = { until: retry ? Infinity : Date.now() + WARNING_SHOW_MS, message: w.message, axis: s.axis,
        state: s.state, retry, rested: false, el };
      box.dataset.key = `warning-${seen}`;
      box.dataset.warning = w.code;
      fill(box, el);
    }
    if (sound) {
      sound.tone(kind === "warn" ? "warn" : "step");
      sound.say(w.message);
    }
    clearTimeout(timer);
    timer = setTimeout(() => box && last && update(last), WARNING_SHOW_MS + 50);
  };

  const update = (s) => {
    last = s;
    if (!box) return;
    const warnings = s.warnings || [];
    const attemptBefore = seenAttempt;
    seenAttempt = s.attempt;
    if (seen === null) seen = warnings.length;
    if (warnings.length > seen) {
      const w = warnings[warnings.length - 1];
      seen = warnings.length;
      // a turn that will be asked again (the warning came with the next attempt): why, until that try starts
      const retry = s.state.startsWith("turn_") && attemptBefore !== null && s.attempt > attemptBefore;
      showWarning(s, w, retry);
    }
    if (shown) {
      // a warning stays a while, unless the instruction itself now says the same or the session has moved on
      // to the step it asked for (a new turn started, or another state): then it would contradict the screen.
      // A retried turn's reason stays through the rest and the prompt to turn again, until that turn starts.
      if (shown.retry && ["settle", "ready", "checking", "pause"].includes(s.phase)) shown.rested = true;
      const movedOn = shown.retry
        ? (s.phase === "turning" && shown.rested) || s.state !== shown.state
        : ["turning", "placing"].includes(s.phase) || s.state === "computing"
          || Boolean(shown.axis && s.axis && s.axis !== shown.axis);
      if (shown.message !== s.prompt && Date.now() < shown.until && !movedOn) return;
      shown = null;
    }
    const resting = s.state === "still" || ["checking", "pause", "settle"].includes(s.phase);
    const key = resting && s.live && s.live.moving ? "moving" : "";
    if (box.dataset.key === key) return;
    box.dataset.key = key;
    delete box.dataset.warning;
    fill(box, key ? notice("warn", "hand", moving) : null);
  };

  return {
    attach(el) {
      box = el;
    },
    update,
    show(el, sticky = false) {
      if (!box) return;
      box.dataset.key = "message";
      fill(box, el);
      if (sticky) shown = { until: Date.now() + WARNING_SHOW_MS, message: null };
    },
    stop() {
      clearTimeout(timer);
      box = null;
    },
  };
}
