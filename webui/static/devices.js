// Step 0: pick the device to calibrate (list or scan), with its status, battery and last calibration.

import { fill, fmtDateTime, h } from "./dom.js";
import { icon } from "./figures.js";
import { problemLine } from "./messages.js";
import { identifyButton } from "./identify.js";
import { heldFact, writeBack } from "./writeback.js";
import { startKit } from "./kit.js";

function status(dev) {
  if (dev.active_kit) return { key: "busy", text: "In a kit's calibration", icon: "busy" };
  if (dev.active_session) return { key: "busy", text: "In a calibration", icon: "busy" };
  if (!dev.available) return { key: "offline", text: "Not reachable", icon: "offline" };
  return { key: "ready", text: "Ready", icon: "ready" };
}

function batteryText(pct) {
  if (typeof pct !== "number") return { text: "not read yet", low: false };
  return { text: `${Math.round(pct)} %`, low: pct < 20 };
}

export function streamText(dev) {
  const range = dev.gyro_full_scale_dps ? ` · measures turns up to ${dev.gyro_full_scale_dps}°/s` : "";
  return `${Number(dev.sample_rate_hz).toLocaleString("en", { maximumFractionDigits: 1 })} readings a second${range}`;
}

function deviceCard(ctx, dev, refresh) {
  const st = status(dev);
  const cur = dev.current_calibration;
  const due = Boolean(dev.calibration_due && dev.calibration_due.due);
  const battery = h("dd", { class: "battery" }, icon("battery"), h("span", null, "not read yet"));
  // each fact once: "gyrocal protocol wearable (simulated: moved during still) · ICM-20948"
  const how = dev.simulated
    ? `simulated${dev.scenario && dev.scenario !== "normal" ? `: ${dev.scenario.replaceAll("_", " ")}` : ""}`
    : dev.transport === "ble" ? "Bluetooth" : null;
  const kind = [dev.model_label ? `${dev.model_label}${how ? ` (${how})` : ""}` : how, dev.sensor_model].filter(Boolean).join(" · ");
  const actions = [];
  if (dev.active_kit) { // turned with the rest of its tray: the kit's page, not this wearable's alone
    actions.push(h("a", { class: "button primary", href: `#/kit/${dev.active_kit}` }, icon("play"), "Resume the kit"));
  } else if (dev.active_session) {
    actions.push(h("a", { class: "button primary", href: `#/session/${dev.active_session}` }, icon("play"), "Resume"));
  } else if (dev.available) {
    actions.push(h("a", { class: "button primary", href: `#/place/${encodeURIComponent(dev.id)}`, "aria-label": `Calibrate ${dev.name || dev.id}` }, icon("play"), "Calibrate"));
  }
  const held = heldFact(dev);
  const write = cur && held && !dev.active_session && dev.available && dev.held_state !== "current"
    ? writeBack(ctx.api, dev.id, cur.id, refresh) : null;
  if (write) actions.push(write.button);
  const ident = identifyButton(ctx.api, dev);
  if (ident) actions.push(ident.button);
  actions.push(h("a", { class: "button", href: `#/history/${encodeURIComponent(dev.id)}`, "aria-label": `History of ${dev.name || dev.id}` }, icon("history"), "History"));
  const card = h("li", { class: "device-card", dataset: { device: dev.id, status: st.key } },
    h("div", { class: "dev-main" },
      h("h2", null, dev.name || dev.id),
      h("p", { class: "dev-sub" }, dev.name && dev.name !== dev.id ? `${dev.id} · ` : "", kind || "")),
    h("dl", { class: "dev-facts" },
      h("div", null, h("dt", null, "Status"), h("dd", { class: `status ${st.key}` }, icon(st.icon), h("span", null, st.text))),
      h("div", null, h("dt", null, "Battery"), battery),
      dev.sample_rate_hz ? h("div", null, h("dt", null, "Readings"),
        h("dd", { class: "stream-settings" }, h("span", null, streamText(dev)))) : null,
      h("div", null, h("dt", null, "Last calibration"),
        h("dd", { class: cur ? (due ? "calibrated due" : "calibrated") : "never" }, icon(cur ? (due ? "warn" : "check") : "info"),
          h("span", null, cur ? `${fmtDateTime(cur.accepted_at)} by ${cur.operator}` : "never calibrated",
            due && cur ? h("span", { class: "due-note" }, ` · due: ${dev.calibration_due.reason}`) : null))),
      held ? h("div", null, h("dt", null, "On the wearable itself"),
        h("dd", { class: `held ${held.cls}` }, icon(held.icon), h("span", null, held.text))) : null),
    dev.limitations && dev.limitations.length
      ? h("ul", { class: "dev-limits", "aria-label": "What this device cannot tell" },
        dev.limitations.map((text) => h("li", null, icon("info"), h("span", null, text))))
      : null,
    dev.unsaved_session && !dev.active_session
      ? h("p", { class: "unsaved", role: "note" }, icon("warn"),
        h("span", null, dev.unsaved_kit
          ? "Result not saved: the last calibration, with its kit, passed but nobody accepted it. "
          : "Result not saved: the last calibration passed but nobody accepted it. "),
        dev.unsaved_kit
          ? h("a", { href: `#/kit/${dev.unsaved_kit}` }, "Open the kit to save or discard")
          : h("a", { href: `#/session/${dev.unsaved_session}` }, "Open it to save or discard"))
      : null,
    h("div", { class: "dev-actions" }, actions,
      dev.available && !dev.active_session
        ? h("label", { class: "kit-pick" }, h("input", { type: "checkbox", value: dev.id, "aria-label": `Put ${dev.name || dev.id} in the kit` }),
          h("span", null, "In the kit"))
        : null),
    write ? write.line : null,
    ident ? ident.line : null);
  card.setBattery = (pct) => {
    const b = batteryText(pct);
    battery.classList.toggle("low", b.low);
    battery.replaceChildren(icon(b.low ? "warn" : "battery"), h("span", null, b.low ? `${b.text} — charge it first` : b.text));
  };
  return card;
}

export function devicesView(ctx) {
  ctx.title("Choose a device");
  let alive = true;
  const list = h("ul", { class: "device-list", "aria-live": "polite", "aria-busy": "true" }, h("li", { class: "loading" }, "Looking for devices…"));
  const scanBtn = h("button", { class: "button", type: "button" }, icon("search"), "Scan for devices");
  const note = h("p", { class: "scan-note", role: "status" });
  const kitBtn = h("button", { class: "button", type: "button", id: "kit-start", disabled: true }, icon("play"), "Calibrate together");
  const picked = () => [...list.querySelectorAll(".kit-pick input:checked")].map((el) => el.value);
  list.addEventListener("change", () => {
    const n = picked().length;
    kitBtn.disabled = n < 2;
    kitBtn.lastChild.textContent = n >= 2 ? `Calibrate ${n} together` : "Calibrate together";
  });
  kitBtn.addEventListener("click", () => startKit(ctx, picked(), note));

  const render = (devices) => {
    if (!alive) return;
    list.setAttribute("aria-busy", "false");
    if (!devices.length) {
      fill(list, h("li", { class: "empty" }, icon("info"), h("span", null, "No devices yet. Switch the wearable on, keep it near this tablet and press “Scan for devices”.")));
      return;
    }
    // the battery level is in the list once the service has read it (null: not read yet)
    fill(list, devices.map((d) => {
      const card = deviceCard(ctx, d, load);
      card.setBattery(d.battery_pct);
      return card;
    }));
  };

  const load = async () => {
    try {
      render(await ctx.api.get("/devices"));
    } catch (err) {
      if (alive && err.status !== 401) ctx.problem(err, "list the devices");
    }
  };

  scanBtn.addEventListener("click", async () => {
    scanBtn.disabled = true;
    note.textContent = "Scanning for wearables nearby…";
    try {
      const out = await ctx.api.request("POST", "/devices/scan", { query: { timeout: 4 } });
      note.textContent = `Found ${out.devices.length} device${out.devices.length === 1 ? "" : "s"}.`;
      await load();
    } catch (err) {
      if (err.status !== 401) note.textContent = problemLine(err);
    } finally {
      scanBtn.disabled = false;
    }
  });

  fill(ctx.main, h("section", { class: "panel", "aria-labelledby": "devices-title" },
    h("div", { class: "panel-head" },
      h("div", null, h("h1", { id: "devices-title" }, "Choose a device"),
        h("p", { class: "lead" }, "Pick the wearable to calibrate, or tick “In the kit” on the wearables of one tray to turn them together.")),
      h("div", { class: "panel-actions" }, scanBtn, kitBtn,
        h("a", { class: "button", href: "#/upload", id: "upload-link" }, icon("upload"), "Calibrate a recording file"),
        h("a", { class: "button", href: "#/noise", id: "noise-link" }, icon("upload"), "Noise from a rest"),
        h("a", { class: "button", href: "#/fleet", id: "fleet-link" }, icon("fleet"), "Fleet"))),
    note, list));
  ctx.focusMain();
  load();
  return () => {
    alive = false;
  };
}
