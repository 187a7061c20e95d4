// A verification turn after Accept: one more full turn about any axis, measured with the new calibration. The
// service streams until it has a rest, the turn and a rest (GET /verifications/{id} while it runs); the page then
// shows the calibrated angle (360° ± its uncertainty when the calibration holds) against the raw one.

import { h, num, sig } from "./dom.js";
import { icon } from "./figures.js";
import { problemLine } from "./messages.js";

const POLL_MS = 400;

/** The verification's result in one sentence and two figures. */
export function verificationLine(v) {
  const ok = v.confirmed;
  return h("div", { class: `verification ${ok ? "ok" : "off"}` },
    h("p", { class: "verification-angles" },
      h("span", { class: "calibrated" }, h("strong", null, `${num(v.calibrated_deg, 1)}° ± ${sig(v.uncertainty_deg, 1)}°`), " calibrated"),
      h("span", { class: "raw" }, `${num(v.raw_deg, 1)}° raw`)),
    h("p", { class: "verification-verdict" }, icon(ok ? "check" : "warn"), h("span", null, ok
      ? `A full turn is 360°: the calibration holds (${num(Math.abs(v.error_deg), 2)}° off, about ${v.dominant_axis.toUpperCase()}).`
      : `A full turn is 360°, and this one measured ${num(v.error_deg, 2)}° off: check the device went back against the block and try again, or calibrate again.`)));
}

/** A "Verify with one turn" button, its live prompt and its result. */
export function verifyTurn(api, calibrationId) {
  const status = h("div", { class: "verify-status", role: "status", "aria-live": "polite" });
  const button = h("button", { class: "button verify", type: "button" }, icon("redo"), "Verify with one turn");
  let alive = true;
  const say = (iconName, text) => status.replaceChildren(h("p", { class: "verify-prompt" }, icon(iconName), h("span", null, text)));
  button.addEventListener("click", async () => {
    button.disabled = true;
    try {
      let run = await api.post(`/calibrations/${calibrationId}/verify`, {});
      while (alive && !["done", "failed"].includes(run.state)) {
        say("clock", run.prompt || "…");
        await new Promise((resolve) => setTimeout(resolve, POLL_MS));
        run = await api.get(`/verifications/${run.verification_id}`);
      }
      if (run.state === "done") fill(run.result);
      else say("warn", run.reason || "The verification did not complete.");
    } catch (err) {
      say("warn", err.status === 401 ? "Please sign in again." : problemLine(err));
    } finally {
      button.disabled = false;
      button.replaceChildren(icon("redo"), "Verify again");
    }
  });
  const fill = (v) => status.replaceChildren(verificationLine(v));
  return { button, status, stop: () => { alive = false; } };
}
