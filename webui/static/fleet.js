// The fleet: every room's gateway and every wearable they see, updated as the fleet changes on any gateway (the
// service pushes the whole view), with a link that follows a running calibration from here and one that opens the
// wizard on the gateway that holds (or last saw) each wearable.

import { fill, fmtDateTime, h } from "./dom.js";
import { icon } from "./figures.js";

const CALIBRATION = {
  current: { text: "Current", icon: "check", cls: "calibrated" },
  due: { text: "Due", icon: "warn", cls: "calibrated due" },
  never: { text: "Never calibrated", icon: "info", cls: "never" },
};

function gatewayItem(g) {
  return h("li", { class: `gateway ${g.alive ? "alive" : "silent"}`, dataset: { gateway: g.name } },
    icon(g.alive ? "ready" : "offline"),
    h("span", null, h("strong", null, g.name), g.this ? " (this one)" : "",
      ` · ${g.alive ? "answering" : "silent since " + fmtDateTime(g.heartbeat_at)} · gyrocal ${g.version}`));
}

const ACTIVITY = { calibration: "In a calibration", verification: "In a verification turn", write: "Being written to" };

function deviceRow(view, d) {
  const cal = CALIBRATION[d.calibration.status];
  const here = d.gateway === view.this_gateway || !d.gateway;
  const href = here ? `#/place/${encodeURIComponent(d.id)}` : d.wizard_url;
  const label = d.in_session ? "Open" : "Calibrate";
  const links = [];
  // a running calibration is followed from any gateway's page; everything else happens on the gateway holding it
  if (d.activity === "calibration" && d.session) {
    links.push(h("a", { class: "button", href: `#/session/${d.session}`, "aria-label": `Follow ${d.id}` }, icon("play"), "Follow"));
  }
  if (!d.in_session || !here) {
    links.push(h("a", { class: "button", href, "aria-label": `${label} ${d.id}${here ? "" : ` on ${d.gateway}`}` },
      icon(here ? "play" : "link"), here ? label : `${label} on ${d.gateway}`));
  }
  return h("tr", { dataset: { device: d.id } },
    h("th", { scope: "row" }, d.name && d.name !== d.id ? `${d.name} (${d.id})` : d.id),
    h("td", null, d.gateway || "—", d.seen_by.length > 1 ? h("span", { class: "due-note" }, ` · seen by ${d.seen_by.length}`) : null),
    h("td", { class: "when" }, d.last_seen ? fmtDateTime(d.last_seen) : "—"),
    h("td", { class: `fleet-status ${d.in_session ? "busy" : "free"}` }, icon(d.in_session ? "busy" : "ready"),
      h("span", null, d.in_session ? ACTIVITY[d.activity] || "In a session" : "Free")),
    h("td", { class: `fleet-cal ${cal.cls}`, title: d.calibration.reason }, icon(cal.icon), h("span", null, cal.text)),
    h("td", { class: "fleet-links" }, links));
}

export function fleetView(ctx) {
  ctx.title("Fleet");
  let alive = true;
  const gateways = h("ul", { class: "gateway-list", "aria-label": "Gateways" });
  const body = h("tbody", { "aria-live": "polite" });
  const stamp = h("p", { class: "scan-note", role: "status" }, "Loading the fleet…");

  const show = (view) => {
    if (!alive) return;
    fill(gateways, view.gateways.map(gatewayItem));
    fill(body, view.devices.length ? view.devices.map((d) => deviceRow(view, d))
      : h("tr", null, h("td", { colspan: 6 }, "No wearable seen by any gateway yet.")));
    stamp.textContent = `${view.devices.length} wearables, ${view.gateways.filter((g) => g.alive).length} of ${view.gateways.length} gateways answering · updated ${fmtDateTime(view.at)}`;
  };

  fill(ctx.main, h("section", { class: "panel", "aria-labelledby": "fleet-title" },
    h("div", { class: "panel-head" },
      h("div", null, h("h1", { id: "fleet-title" }, "Fleet"),
        h("p", { class: "lead" }, "Every room's gateway and every wearable they see.")),
      h("div", { class: "panel-actions" }, h("a", { class: "button", href: "#/devices" }, icon("back"), "This room's devices"))),
    gateways, stamp,
    h("div", { class: "table-wrap" },
      h("table", { class: "fleet-table" },
        h("thead", null, h("tr", null, ["Wearable", "Gateway", "Last seen", "Session", "Calibration"].map((t) => h("th", { scope: "col" }, t)),
          h("th", { scope: "col" }, h("span", { class: "visually-hidden" }, "Open")))),
        body))));
  ctx.focusMain();
  const stop = ctx.api.followFleet(show, (link) => {
    if (alive && link !== "open") stamp.textContent = "The connection to the service was interrupted; reconnecting…";
  });
  return () => {
    alive = false;
    stop();
  };
}
