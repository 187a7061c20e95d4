// Calibrate a recording file: a CSV made by any wearable (native, imucal or raw counts), of the paper's
// protocol, Ferraris' or re-orientations between rests. The service calibrates and stores it as a session,
// whose result the page then shows like a guided one.

import { fill, h } from "./dom.js";
import { icon } from "./figures.js";
import { problemLine } from "./messages.js";

const PROTOCOLS = [
  ["auto", "Recognise it (paper turns, Ferraris, re-orientations between rests)"],
  ["paper", "Rests and a full turn about x, y and z"],
  ["ferraris", "Ferraris: six static poses and three turns"],
  ["multi-position", "Re-orientations between rests (needs the accelerometer)"],
];

function field(id, label, input, hint) {
  return h("div", { class: "field" }, h("label", { for: id }, label), input, hint ? h("p", { class: "muted", id: `${id}-hint` }, hint) : null);
}

export function uploadView(ctx, deviceId) {
  ctx.title("Calibrate a recording file");
  const file = h("input", { id: "up-file", type: "file", accept: ".csv,.txt,.mat,text/csv,text/plain", required: true });
  const device = h("input", { id: "up-device", type: "text", value: deviceId || "", required: true, maxlength: 64,
    pattern: "[A-Za-z0-9_.:\\-]+", autocomplete: "off" });
  const protocol = h("select", { id: "up-protocol" }, PROTOCOLS.map(([v, t]) => h("option", { value: v }, t)));
  const fs = h("input", { id: "up-fs", type: "number", min: "0", step: "any", placeholder: "from the time column" });
  const gyroCounts = h("input", { id: "up-gyro-counts", type: "number", min: "0", step: "any", placeholder: "deg/s already" });
  const accelCounts = h("input", { id: "up-accel-counts", type: "number", min: "0", step: "any", placeholder: "g or m/s² already" });
  const sections = h("input", { id: "up-sections", type: "file", accept: ".json,application/json" });
  const accelFile = h("input", { id: "up-accel-file", type: "file" });
  const status = h("p", { class: "scan-note", role: "status", "aria-live": "polite" });
  const send = h("button", { class: "button primary", type: "submit" }, icon("check"), "Calibrate");
  const form = h("form", { class: "upload-form", novalidate: true },
    field("up-device", "Device", device, "The wearable the recording came from; its calibration is stored under this name."),
    field("up-file", "Recording (CSV)", file, "Native (t,gx,gy,gz,…), imucal (gyr_x,…) or raw counts with a part column; "
      + "for imu_tk's two files, its gyroscope file."),
    field("up-accel-file", "Accelerometer file (imu_tk, optional)", accelFile,
      "imu_tk keeps the accelerometer in a file of its own (rows t x y z of raw counts): give it here."),
    field("up-protocol", "What was done", protocol),
    field("up-fs", "Sample rate (Hz)", fs, "Only for a file without a time column (e.g. 102.4 for imucal's session)."),
    field("up-gyro-counts", "Gyro counts per °/s", gyroCounts, "Only for raw counts (e.g. 16.4 at ±2000 °/s)."),
    field("up-accel-counts", "Accelerometer counts per g", accelCounts, "Only for raw counts (e.g. 2048 at ±16 g)."),
    field("up-sections", "Labelled sections (JSON, optional)", sections, "imucal's section list, used instead of finding the stages."),
    status, send);

  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const id = device.value.trim();
    if (!id || !device.checkValidity()) {
      status.textContent = "Give the device's name: letters, digits and . _ : - only.";
      device.focus();
      return;
    }
    if (!file.files.length) {
      status.textContent = "Choose the recording's CSV file.";
      file.focus();
      return;
    }
    const query = { protocol: protocol.value };
    if (fs.value) query.fs = fs.value;
    if (gyroCounts.value) query.gyro_counts_per_dps = gyroCounts.value;
    if (accelCounts.value) query.accel_counts_per_g = accelCounts.value;
    send.disabled = true;
    status.textContent = "Calibrating the recording…";
    try {
      if (sections.files.length) query.sections = await sections.files[0].text();
      let body = { csv: await file.files[0].text() };
      if (accelFile.files.length) {
        // imu_tk's layout: the two files as the parts of one multipart body
        const form = new FormData();
        form.append("gyro", file.files[0]);
        form.append("accel", accelFile.files[0]);
        body = { form };
        query.layout = "imu_tk";
      }
      const out = await ctx.api.request("POST", `/devices/${encodeURIComponent(id)}/calibrate`, { ...body, query });
      status.textContent = `Calibrated as ${out.protocol}.`;
      ctx.go(`#/session/${out.session_id}`);
    } catch (err) {
      if (err.status !== 401) status.textContent = problemLine(err);
    } finally {
      send.disabled = false;
    }
  });

  fill(ctx.main, h("section", { class: "panel", "aria-labelledby": "upload-title" },
    h("div", { class: "panel-head" },
      h("div", null, h("h1", { id: "upload-title" }, "Calibrate a recording file"),
        h("p", { class: "lead" }, "A recording made without the guided steps: the service finds what was done and calibrates it."))),
    form));
  ctx.focusMain();
  return null;
}
