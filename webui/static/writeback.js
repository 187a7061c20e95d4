// Writing a calibration to a wearable that can hold one: the button, its progress, and what the device
// holds afterwards (read back and verified by the service).

import { h } from "./dom.js";
import { icon } from "./figures.js";
import { problemLine } from "./messages.js";

/** What a device card says the wearable holds: {cls, icon, text}, or null when it cannot hold one. */
export function heldFact(dev) {
  if (!dev.write_back) return null;
  const cur = dev.current_calibration;
  switch (dev.held_state) {
    case "current":
      return { cls: "held-current", icon: "check", text: `its latest calibration (#${dev.held_calibration_id})` };
    case "other":
      return { cls: "held-other", icon: "warn", text: cur ? `an older calibration (#${dev.held_calibration_id}), not the latest (#${cur.id})` : `calibration #${dev.held_calibration_id}, not known here` };
    case "none":
      return { cls: "held-none", icon: "info", text: "no calibration yet: gyrocal corrects its readings" };
    default:
      return { cls: "held-unknown", icon: "info", text: "known once it next connects" };
  }
}

/** A "Store on the wearable" button and its status line; ``done(out)`` runs after a verified write. */
export function writeBack(api, deviceId, calibrationId, done) {
  const label = "Store on the wearable";
  const line = h("p", { class: "writeback-status", role: "status" });
  const button = h("button", { class: "button write-back", type: "button" }, icon("save"), label);
  button.addEventListener("click", async () => {
    button.disabled = true;
    button.replaceChildren(icon("clock"), "Storing…");
    line.className = "writeback-status";
    line.textContent = "Sending the calibration and reading it back…";
    try {
      const body = calibrationId ? { calibration_id: calibrationId } : {};
      const out = await api.post(`/devices/${encodeURIComponent(deviceId)}/calibration/write`, body);
      line.classList.add("ok");
      line.replaceChildren(icon("check"), h("span", null, `Written and verified: the device holds calibration #${out.calibration_id}.`));
      button.replaceChildren(icon("save"), "Store again");
      if (done) done(out);
    } catch (err) {
      line.classList.add("error");
      line.replaceChildren(icon("warn"), h("span", null, err.status === 401 ? "Please sign in again." : problemLine(err)));
      button.replaceChildren(icon("save"), label);
    } finally {
      button.disabled = false;
    }
  });
  return { button, line };
}
