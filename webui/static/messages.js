// What the page says: a headline for every session state, and for every way a session can end
// (the service's reason codes) a title and the fix. The service's own sentence says what happened.

import { AXIS_LABEL } from "./dom.js";
import { TURN_SENTENCE, TURN_SHORT } from "./guide.js";

const ax = (a) => AXIS_LABEL[a] || String(a || "").toUpperCase();

/** The short instruction shown big for a running session; the service's prompt goes beneath it. */
export function headline(snap, deviceName) {
  const axis = snap.axis;
  switch (snap.state) {
    case "connecting":
      return `Connecting to ${deviceName}…`;
    case "still":
      return "Hold still";
    case "turn_x":
    case "turn_y":
    case "turn_z":
      switch (snap.phase) {
        case "settle":
          return "Put it back and hold still";
        case "returning":
          return "Putting it back against the block";
        case "turning":
          return `Turning about ${ax(axis)}`;
        case "placing":
          return "Hold it still";
        case "checking":
          return `Checking turn ${ax(axis)} — hold still`;
        case "pause":
          return `${ax(axis)} done — hold still`;
        default:
          return `Turn ${ax(axis)}: ${TURN_SHORT[axis] || "one full turn"}`;
      }
    case "reconnecting":
      return "Connection lost";
    case "computing":
      return "Computing…";
    default:
      return snap.prompt || "";
  }
}

/** The plain sentence under the headline (the service's prompt, made shorter where it helps). */
export function subline(snap) {
  if (snap.state.startsWith("turn_") && snap.phase === "ready") {
    // the turn in a sentence, as the picture beside shows it
    return TURN_SENTENCE[snap.axis] || snap.prompt || "";
  }
  if (snap.state.startsWith("turn_") && snap.phase === "returning") {
    return `Once it rests in its place, turn it one full turn about ${ax(snap.axis)}.`;
  }
  if (snap.state.startsWith("turn_") && snap.phase === "turning") {
    const target = snap.live && snap.live.target_deg;
    return target
      ? `Stop when the gauge reads ${Math.round(target)}° and the device is back in its place against the block.`
      : "Stop when the device is back in its place against the block.";
  }
  return snap.prompt || "";
}

// title: what went wrong, in a few words; fix: the one thing to do next; icon: a glyph name (figures.js)
// the end reasons of a turn done wrong (a warning too, when the turn is asked again)
export const TURN_FAULTS = new Set(["wrong_axis", "too_fast", "turn_incomplete", "turn_too_far", "turn_too_long", "no_motion"]);

export const REASONS = {
  connect_failed: { title: "The device did not connect", fix: "Switch the device on, check it is charged and near the receiver, then try again.", icon: "link" },
  not_still: { title: "The device did not stay still", fix: "Put it flat against the block and take your hands off it until the ring is full.", icon: "hand" },
  no_motion: { title: "No turn was made", fix: "Start again and turn the device as soon as the turn is asked for.", icon: "clock" },
  moved_during_pause: { title: "The device moved during a pause", fix: "After each turn, leave the device still against the block until the ring is full.", icon: "hand" },
  wrong_axis: { title: "The turn was about the wrong axis", fix: "Turn about the axis shown on the screen, marked on the device's case.", icon: "axis" },
  too_fast: { title: "The turn was too fast", fix: "Turn more slowly: take 2 to 4 seconds for the full turn.", icon: "fast" },
  turn_incomplete: { title: "The turn was not a full turn", fix: "Turn all the way round until the device is back in its place against the block.", icon: "axis" },
  turn_too_far: { title: "The device was turned too far", fix: "Turn exactly once, and stop when the device is back against the block.", icon: "axis" },
  turn_too_long: { title: "The turn took too long", fix: "Make one smooth turn, then put the device down against the block.", icon: "clock" },
  sample_loss: { title: "Data was lost on the radio link", fix: "Keep the device within a few metres of the receiver, with nothing in between.", icon: "link" },
  link_lost: { title: "The connection was lost", fix: "Check the device is switched on, charged and close to the receiver, then try again.", icon: "link" },
  unreadable_data: { title: "The device sends data this version cannot read", fix: "Not your turns, not the radio: start again. If it happens again, the device's firmware and this service do not match: tell the administrator.", icon: "fail" },
  device_clock: { title: "The device's clock cannot be trusted", fix: "Not your turns, not the radio: switch the device off and on and start again. If it happens again, its firmware is at fault: tell the administrator.", icon: "fail" },
  sensor_fault: { title: "The device's sensor is faulty", fix: "Not your turns: switch the device off and on and start again. If it happens again, the device needs repair.", icon: "fail" },
  out_of_tolerance: { title: "The result is outside the tolerances", fix: "Press Redo and calibrate again, doing what is said above.", icon: "fail" },
  calibration_failed: { title: "The calibration could not be computed", fix: "Start again, following each step on the screen.", icon: "fail" },
  departed: { title: "The wearable came apart from its kit", fix: "Seat it firmly in its slot, then calibrate it alone or with the kit.", icon: "hand" },
  timeout: { title: "The calibration took too long", fix: "Start again; the whole calibration takes about a minute.", icon: "clock" },
  service_overloaded: { title: "The service was too busy to follow", fix: "Not the device, nor your turns: start again. If it happens again, tell the administrator the service is overloaded.", icon: "clock" },
  service_restarted: { title: "The service was restarted", fix: "Start a new calibration.", icon: "fail" },
  gateway_lost: { title: "The room's gateway stopped answering", fix: "The device is free again: start a new calibration from any gateway that sees it.", icon: "fail" },
  internal_error: { title: "Something went wrong in the service", fix: "Start again. If it happens again, report it with the time shown below.", icon: "fail" },
  cancelled: { title: "Calibration cancelled", fix: "Nothing was saved: the device keeps its previous calibration.", icon: "stop" },
};

export function reasonFor(code, snap = null) {
  const r = REASONS[code] || { title: "The calibration stopped", fix: "Start a new calibration.", icon: "fail" };
  if (code === "no_motion" && snap && (Object.keys(snap.turns || {}).length || (snap.attempt || 1) > 1)) {
    // turns were made: it is the one asked after them that was not started
    return { ...r, title: "The next turn was not started in time", fix: "Start again: the turns are asked from the beginning, each as the screen shows it." };
  }
  return r;
}

/** The time left for an overdue turn, in words (null while there is no such limit near). */
export function timeLeft(snap, showBelowS = 40) {
  const left = snap.time_left_s;
  if (left == null || snap.phase !== "ready" || left > showBelowS) return null;
  return `No turn yet: the calibration stops in ${Math.max(0, Math.ceil(left))} s unless the turn starts.`;
}

/** A failed request in one line, for a form's status: the service's reason, or that it did not answer. */
export function problemLine(err) {
  return err.network ? "The service cannot be reached; try again." : err.detail;
}

/** A failed request, explained: {title, text, fix, signIn?}. */
export function requestProblem(err, what) {
  if (err.network) {
    return { title: "The service cannot be reached", text: `Could not ${what}: the gyrocal service did not answer.`, fix: "Check that the service is running and this tablet is on its network, then try again." };
  }
  switch (err.status) {
    case 401:
      return { title: "Please sign in again", text: err.detail, fix: "Your sign-in has expired or was revoked.", signIn: true };
    case 404:
      return { title: "Not found", text: err.detail, fix: "Go back to the device list and choose the device again." };
    case 409:
      return { title: "Not possible right now", text: err.detail, fix: "The device or the session is busy or has moved on; see its current state." };
    case 413:
    case 415:
    case 422:
    case 400:
      return { title: "The request was refused", text: err.detail, fix: "Check the values and try again." };
    case 503:
      return { title: "The store is unavailable", text: err.detail, fix: "Nothing was changed. Wait a moment and try again." };
    default:
      return { title: `The service answered with an error (${err.status})`, text: err.detail, fix: "Try again. If it happens again, report it." };
  }
}

export const STEP_LABELS = ["Place", "Hold still", "Turn X", "Turn Y", "Turn Z", "Result", "Saved"];

/** Step 1..7 of the wizard for a snapshot. */
export function stepOf(snap) {
  switch (snap.state) {
    case "connecting":
      return 1;
    case "still":
      return 2;
    case "turn_x":
      return 3;
    case "turn_y":
      return 4;
    case "turn_z":
      return 5;
    case "computing":
    case "done":
    case "failed":
    case "cancelled":
      return snap.decision === "accepted" ? 7 : 6;
    default:
      return null;
  }
}
